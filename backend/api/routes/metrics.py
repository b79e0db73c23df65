"""``GET /metrics``: Prometheus text format, built from the same counters ``/api/stats`` shows."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import PlainTextResponse

from backend.api.deps import VIEWER, ServicesDep
from backend.core.metrics import Exposition
from backend.services.container import Services

router = APIRouter(tags=["health"], dependencies=[VIEWER])  # Prometheus: a viewer token as bearer


def render_metrics(services: Services) -> str:
    out = Exposition()
    robots = list(services.registry.robots.values())
    out.metric("fleet_robots", "gauge", "Robots known to the server.", len(robots))
    out.metric("fleet_robots_online", "gauge", "Robots online now.", sum(1 for r in robots if r.online))
    out.family("fleet_telemetry_messages_total", "counter", "Telemetry messages received, per stream.")
    out.family("fleet_telemetry_gaps_total", "counter", "Messages missing by seq gaps, per stream.")
    per_stream: dict[str, tuple[int, int]] = {}
    for st in robots:
        for name, ss in st.streams.items():
            count, gaps = per_stream.get(name, (0, 0))
            per_stream[name] = (count + ss.count, gaps + ss.gaps)
    for name, (count, gaps) in sorted(per_stream.items()):
        out.sample("fleet_telemetry_messages_total", count, {"stream": name})
        out.sample("fleet_telemetry_gaps_total", gaps, {"stream": name})

    rejects = services.rejects.snapshot()
    out.family("fleet_rejects_total", "counter", "Refused input (MQTT payloads, topics), by reason.")
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

    writer = services.writer.stats()
    out.metric("fleet_store_queue_rows", "gauge", "Rows waiting for the database writer (its lag).",
               writer.get("queued", 0))
    out.metric("fleet_store_rows_written_total", "counter", "Rows committed.", writer.get("rows_written", 0))
    out.metric("fleet_store_rows_dropped_total", "counter", "Rows dropped (writer queue full).",
               writer.get("rows_dropped", 0))
    out.metric("fleet_store_batches_total", "counter", "Batches committed.", writer.get("batches", 0))
    batches = writer.get("batches", 0)
    out.metric("fleet_store_batch_rows_mean", "gauge", "Mean rows per committed batch.",
               writer.get("rows_written", 0) / batches if batches else 0.0)
    out.metric("fleet_store_errors_total", "counter", "Failed database batches.", writer.get("errors", 0))

    ws = services.hub.stats()
    out.metric("fleet_ws_clients", "gauge", "Live WebSocket clients.", ws.get("clients", 0))
    out.metric("fleet_ws_dropped_total", "counter", "Live messages dropped for slow clients (coalesced).",
               ws.get("dropped", 0))
    cam = services.camera.stats()
    out.metric("fleet_camera_frames_total", "counter", "Camera frames received.", cam["frames_in"])
    out.metric("fleet_camera_viewers", "gauge", "Live camera viewers.", cam["viewers"])

    out.histogram("fleet_command_ack_seconds", "Seconds from command creation to each ack, by status.",
                  services.commands.latency, "status")
    out.metric("fleet_estop_engaged", "gauge", "1 while the fleet e-stop is latched.",
               int(bool(services.estop.state.engaged)))
    return out.render()


@router.get("/metrics", response_class=PlainTextResponse)
async def metrics(services: ServicesDep) -> PlainTextResponse:
    return PlainTextResponse(render_metrics(services), media_type="text/plain; version=0.0.4; charset=utf-8")
