"""``GET /metrics``: Prometheus text format, built from the same counters ``/api/stats`` shows."""

from __future__ import annotations

import time

from fastapi import APIRouter
from fastapi.responses import PlainTextResponse

from backend.api.deps import METRICS, ServicesDep
from backend.core.metrics import CONTENT_TYPE, Exposition
from backend.services.lifecycle import Services

router = APIRouter(tags=["health"], dependencies=[METRICS])  # Prometheus: a metrics token as bearer

#: the database writer's bookkeeping (store/writer.py): (metric, kind, stats key, help)
STORE_METRICS = (
    ("fleet_store_rows_rejected_total", "counter", "rows_rejected", "Rows the database refused (bad data): lost."),
    ("fleet_store_retries_total", "counter", "retries", "Failed commits retried later (database unavailable)."),
    ("fleet_store_failing", "gauge", "failing", "1 while the database is unavailable and writes wait for a retry."),
    ("fleet_store_ops_retrying", "gauge", "ops_retrying", "Writes (audit, commands, events) waiting for a retry."),
    ("fleet_store_ops_dropped_total", "counter", "ops_dropped", "Writes given up (queue or retry queue full)."),
    ("fleet_store_ops_refused_total", "counter", "ops_refused", "Writes the database refused (bad data, a bug)."),
    ("fleet_store_acks_total", "counter", "acks", "Broker acks released after the commit of their rows."),
    ("fleet_store_acks_withheld_total", "counter", "acks_withheld", "Broker acks withheld: messages not stored."),
    ("fleet_store_slow_batches_total", "counter", "slow_batches", "Telemetry batches slower than 0.2 s to commit."),
)


def render_metrics(services: Services) -> str:
    out = Exposition()
    robots = list(services.registry.robots.values())
    out.metric("fleet_robots", "gauge", "Robots known to the server.", len(robots))
    out.metric("fleet_robots_online", "gauge", "Robots online now.", sum(1 for r in robots if r.online))
    out.family("fleet_telemetry_messages_total", "counter", "Telemetry messages received, per stream.", ["stream"])
    out.family("fleet_telemetry_gaps_total", "counter", "Messages missing by seq gaps, per stream.", ["stream"])
    per_stream: dict[str, tuple[int, int]] = {}
    for st in robots:
        for name, ss in st.streams.items():
            count, gaps = per_stream.get(name, (0, 0))
            per_stream[name] = (count + ss.count, gaps + ss.gaps)
    for name, (count, gaps) in sorted(per_stream.items()):
        out.sample("fleet_telemetry_messages_total", count, {"stream": name})
        out.sample("fleet_telemetry_gaps_total", gaps, {"stream": name})

    if services.repair is not None:  # gap repair: what became of the missing messages
        out.family("fleet_telemetry_gaps_open", "gauge", "Missing messages being repaired, per stream.", ["stream"])
        out.family(
            "fleet_telemetry_gaps_repaired_total", "counter", "Missing messages repaired, per stream.", ["stream"]
        )
        out.family(
            "fleet_telemetry_gaps_lost_total", "counter", "Missing messages lost for good, per stream.", ["stream"]
        )
        for name, (_detected, open_n, repaired, lost) in sorted(services.repair.totals_by_stream().items()):
            out.sample("fleet_telemetry_gaps_open", open_n, {"stream": name})
            out.sample("fleet_telemetry_gaps_repaired_total", repaired, {"stream": name})
            out.sample("fleet_telemetry_gaps_lost_total", lost, {"stream": name})
        out.metric(
            "fleet_telemetry_repair_requests_total",
            "counter",
            "Gap repair requests sent to robots.",
            services.repair.requests_sent,
        )

    rejects = services.rejects.snapshot()
    out.family("fleet_rejects_total", "counter", "Refused input (MQTT payloads, topics), by reason.", ["reason"])
    by_reason = rejects.get("by_reason", {})
    assert isinstance(by_reason, dict)
    for reason, n in sorted(by_reason.items()):
        out.sample("fleet_rejects_total", n, {"reason": str(reason)})

    mqtt = services.bridge.stats()
    connected = int(bool(mqtt.get("connected")))
    out.metric("fleet_mqtt_connected", "gauge", "1 when the server's MQTT link is up.", connected)
    for key in ("received", "dropped"):
        if key in mqtt:
            out.metric(f"fleet_mqtt_inbox_{key}_total", "counter", f"MQTT inbox messages {key}.", mqtt[key])
    if "redelivery_reconnects" in mqtt:  # withheld acks: broker slots held until a reconnect (comms/redelivery.py)
        held = mqtt["acks_withheld_now"]
        out.metric("fleet_mqtt_acks_withheld", "gauge", "Acks withheld on this connection (broker slots held).", held)
        out.metric(
            "fleet_mqtt_redelivery_reconnects_total",
            "counter",
            "Reconnects made so that the broker delivers withheld messages again.",
            mqtt["redelivery_reconnects"],
        )

    writer = services.writer.stats()
    out.metric(
        "fleet_store_queue_rows", "gauge", "Rows waiting for the database writer (its lag).", writer.get("queued", 0)
    )
    out.metric("fleet_store_rows_written_total", "counter", "Rows committed.", writer.get("rows_written", 0))
    out.metric(
        "fleet_store_rows_dropped_total",
        "counter",
        "Rows not stored (writer queue or retry buffer full): unacked, the broker sends them again.",
        writer.get("rows_dropped", 0),
    )
    out.metric("fleet_store_batches_total", "counter", "Batches committed.", writer.get("batches", 0))
    batches = writer.get("batches", 0)
    out.metric(
        "fleet_store_batch_rows_mean",
        "gauge",
        "Mean rows per committed batch.",
        writer.get("rows_written", 0) / batches if batches else 0.0,
    )
    out.metric("fleet_store_errors_total", "counter", "Failed database batches.", writer.get("errors", 0))
    for name, kind, key, help_text in STORE_METRICS:
        out.metric(name, kind, help_text, writer.get(key, 0))

    ws = services.hub.stats()
    out.metric("fleet_ws_clients", "gauge", "Live WebSocket clients.", ws.get("clients", 0))
    out.metric(
        "fleet_ws_dropped_total", "counter", "Live messages dropped for slow clients (coalesced).", ws.get("dropped", 0)
    )
    cam = services.camera.stats()
    out.metric("fleet_camera_frames_total", "counter", "Camera frames received.", cam["frames_in"])
    out.metric("fleet_camera_viewers", "gauge", "Live camera viewers.", cam["viewers"])

    out.histogram(
        "fleet_command_ack_seconds",
        "Seconds from command creation to each ack, by status.",
        services.commands.latency,
        "status",
    )
    out.metric(
        "fleet_estop_engaged", "gauge", "1 while the fleet e-stop is latched.", int(bool(services.estop.state.engaged))
    )
    # each robot's health, for labs whose Prometheus alerts on it (deploy/prometheus/alerts.yml)
    health_gauges = {
        "battery_pct": "Battery charge, percent.",
        "cpu_temp_c": "CPU temperature, degrees Celsius.",
        "wifi_rssi_dbm": "Wi-Fi signal, dBm.",
        "clock_offset_ms": "Clock offset to the base station, ms.",
    }
    for field, help_text in health_gauges.items():
        out.family(f"fleet_robot_{field}", "gauge", help_text, ["robot"])
    out.family("fleet_robot_position_age_seconds", "gauge", "Seconds since the robot's last position.", ["robot"])
    out.family("fleet_robot_motor_fault", "gauge", "1 while the motor driver reports a fault.", ["robot"])
    now = time.time()
    for st in robots:
        if not st.online:
            continue
        for field in health_gauges:
            value = (st.health or {}).get(field)
            if isinstance(value, int | float) and not isinstance(value, bool):
                out.sample(f"fleet_robot_{field}", value, {"robot": st.id})
        if st.position is not None:
            out.sample("fleet_robot_position_age_seconds", max(0.0, now - st.position.ts), {"robot": st.id})
        fault = (st.health or {}).get("motor_fault")
        if isinstance(fault, bool):
            out.sample("fleet_robot_motor_fault", int(fault), {"robot": st.id})
    out.family("fleet_alarms_active", "gauge", "Alarms active (not yet acknowledged), by severity.", ["severity"])
    for severity, n in sorted(services.alarms.active_counts().items()):
        out.sample("fleet_alarms_active", n, {"severity": severity})
    _loop_and_pools(out, services)
    return out.render()


def _loop_and_pools(out: Exposition, services: Services) -> None:
    """The event loop's stalls (core/loopwatch.py) and the pools that keep CPU work off it (core/workpool.py)."""
    loop = services.watchdog
    out.metric(
        "fleet_event_loop_stalls_total",
        "counter",
        "Event-loop stalls of 0.2 s or more (each raises the loop_stall alarm).",
        loop.alarmed_stalls,
    )
    lag_s = loop.max_lag_ms / 1000
    out.metric("fleet_event_loop_max_lag_seconds", "gauge", "The longest the event loop was late, seconds.", lag_s)
    pools = {"planner": services.missions.planner.stats(), "passwords": services.passwords.stats()}
    for name, kind, key, help_text in (
        ("fleet_pool_jobs_total", "counter", "done", "Jobs run on the pool (mission plans, password checks)."),
        ("fleet_pool_refused_total", "counter", "refused", "Jobs refused at once (503): the pool's queue was full."),
        ("fleet_pool_jobs_pending", "gauge", "pending", "Jobs running or waiting on the pool."),
        ("fleet_pool_busy_seconds_total", "counter", "busy_s", "Seconds the pool's threads spent on jobs."),
    ):
        out.family(name, kind, help_text, ["pool"])
        for pool, stats in pools.items():
            out.sample(name, stats[key], {"pool": pool})


@router.get("/metrics", response_class=PlainTextResponse)
async def metrics(services: ServicesDep) -> PlainTextResponse:
    return PlainTextResponse(render_metrics(services), media_type=CONTENT_TYPE)
