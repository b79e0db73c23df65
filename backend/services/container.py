"""The composition root: builds every service with its dependencies as keyword arguments, in dependency
order (the running set, its start, stop and tick: lifecycle.py)."""

from __future__ import annotations

import asyncio
import logging
import time
from functools import partial

from pydantic import ValidationError

from backend.comms.address import default_client_id
from backend.comms.base import AckToken, InboundMessage, Subscription
from backend.comms.client_id import server_client_id
from backend.comms.mqtt_bridge import MqttBridge
from backend.core.alarm_rules import LOOP_STALL
from backend.core.config import Settings
from backend.core.loopwatch import LoopWatchdog
from backend.core.rejects import InboundRejects
from backend.core.workpool import WorkPool
from backend.services.access.audit import AuditService
from backend.services.access.auth import server_key
from backend.services.control.commands import CommandService
from backend.services.control.leases import LeaseService
from backend.services.dispatcher import Dispatcher
from backend.services.fleet.clock import ClockService
from backend.services.fleet.forget import RobotForgetter
from backend.services.fleet.heartbeat import HeartbeatPublisher
from backend.services.fleet.poses import PoseBoard, PosePublisher
from backend.services.fleet.registry import Registry
from backend.services.legacy.bridge import LegacyAdapter
from backend.services.legacy.registrations import LegacyRegistrations
from backend.services.legacy.relay import LegacyCommandRelay
from backend.services.lifecycle import Services
from backend.services.live.camera import CameraRelay, Frame
from backend.services.live.foxglove import FoxgloveLive
from backend.services.live.hub import LiveHub
from backend.services.missions.service import MissionService
from backend.services.missions.site_source import ServedSite
from backend.services.rehearsal import RehearsalService
from backend.services.runs.frames import FrameStore
from backend.services.runs.recorder import RunService
from backend.services.safety.alarms import AlarmService
from backend.services.safety.estop import EStopService
from backend.services.safety.holds import HoldService
from backend.services.safety.latches import LatchSync
from backend.services.site.service import SiteService
from backend.services.telemetry.ingest import TelemetryIngest
from backend.services.telemetry.readers import ExportGate, Readers
from backend.services.telemetry.repair import GapRepair
from backend.services.telemetry.rollups import RollupWorker
from backend.store import alarms as alarm_store
from backend.store import latches as latch_store
from backend.store import missions as mission_store
from backend.store import repository as repo
from backend.store import runs as run_store
from backend.store.db import create_db_engine, create_reader_engine, upgrade_to_head
from backend.store.writer import BatchWriter
from fleet_protocol import (
    LEGACY_COMMAND_TOPIC,
    LEGACY_SENSOR_FILTER,
    LEGACY_STOP,
    QOS_ACK,
    QOS_CONFIG,
    QOS_ESTOP,
    QOS_HOLD,
    QOS_LEGACY_STOP,
    QOS_POSES,
    QOS_REPAIR,
    QOS_STATUS,
    QOS_SYNC,
    QOS_TELEMETRY,
    QOS_TIME,
    Site,
    Topics,
    shared_subscription,
)

log = logging.getLogger(__name__)

#: the missions' planner pool: two threads (a plan within the limits takes up to about a second of one core)
#: and a few plans waiting; more are refused (503 planner_busy)
PLANNER_WORKERS = 2
PLANNER_QUEUE = 4
#: password checks (scrypt, 16 MiB and ~50 ms each) for logins and password changes: the same, smaller
PASSWORD_WORKERS = 2
PASSWORD_QUEUE = 16


async def build_services(settings: Settings) -> Services:
    """Every service gets its dependencies as keyword arguments; nothing is patched after construction.
    The two cycles (bridge -> dispatcher -> services, writer -> bridge acks) go through late-bound calls."""
    topics = Topics(settings.topic_prefix)
    engine = create_db_engine(settings)
    await asyncio.to_thread(upgrade_to_head, engine)
    robots = await asyncio.to_thread(repo.load_robots, engine)

    bridge: MqttBridge | None = None
    dispatcher: Dispatcher | None = None

    def connection_changed(connected: bool) -> None:
        if dispatcher is not None:
            dispatcher.connection_changed(connected)

    def ack_committed(tokens: list[AckToken]) -> None:
        """Broker acks follow the DB commit of what each message caused (see store/writer.py)."""
        assert bridge is not None
        bridge.ack(tokens)

    def ack_withheld(tokens: list[AckToken]) -> None:
        """Never acked (not stored): the bridge reconnects once the writer caught up, and they come again."""
        assert bridge is not None
        bridge.withhold(tokens)

    def on_messages(batch: list[InboundMessage]) -> None:
        assert dispatcher is not None
        dispatcher.handle_batch(batch)

    def stored_via_shared() -> bool:
        return bridge is not None and bridge.v5

    writer = BatchWriter(
        engine=engine,
        batch_rows=settings.writer_batch_rows,
        interval_s=settings.writer_batch_interval_s,
        queue_max=settings.writer_queue_max,
        on_acks=ack_committed,
        retry_max=settings.writer_retry_max,
        on_withheld=ack_withheld,
    )
    writer.start()
    # Rejects land in the events table at the same (rate-limited) pace as the log.
    rejects = InboundRejects(on_logged=lambda d: writer.submit(repo.insert_event(time.time(), "reject", None, d)))
    hub = LiveHub(queue_max=settings.ws_client_queue_max, flush_interval_s=settings.ws_flush_interval_s)
    registry = Registry(
        writer=writer,
        hub=hub,
        stale_after_s=settings.stale_after_s,
        legacy_offline_after_s=settings.legacy_offline_after_s,
    )
    registry.load(robots)
    foxglove = _foxglove(settings)
    poses = PoseBoard(registry)  # every robot's latest fix, for the fleet poses and the goto check
    ingest = TelemetryIngest(
        registry=registry,
        writer=writer,
        hub=hub,
        topics=topics,
        buffered=True,  # rows go to the writer once per MQTT drain, then that drain's acks
        stored_via_shared=stored_via_shared if settings.ingest_shared_group else None,
        taps=[poses.on_telemetry, *([foxglove.on_telemetry] if foxglove is not None else [])],
    )
    # the public name (heartbeat, missions, stats) and the id it connects with (name + secret suffix)
    name = settings.mqtt_client_id or default_client_id()
    bridge = MqttBridge(
        url=settings.mqtt_url,
        subscriptions=_subscriptions(settings, topics),
        on_messages=on_messages,
        on_connection_change=connection_changed,
        client_id=await asyncio.to_thread(server_client_id, name, settings.server_data_dir),
        name=name,
        keepalive=settings.mqtt_keepalive_s,
        queue_max=settings.inbound_queue_max,
        protocol=settings.mqtt_protocol,
        session_expiry_s=settings.mqtt_session_expiry_s,
        receive_maximum=settings.mqtt_receive_maximum,
        on_store=ingest.store_batch,
        on_ack_marker=ingest.drained,
        credentials=settings.mqtt_credentials,
        fast_path=settings.mqtt_fast_path,
        redeliver_when=writer.caught_up,
        # a crashed server stops every robot on the old framework (they have no deadman of their own)
        will=(LEGACY_COMMAND_TOPIC, LEGACY_STOP, QOS_LEGACY_STOP) if settings.legacy_enabled else None,
    )
    audit = AuditService(writer=writer)
    site = SiteService(
        engine=engine,
        publisher=bridge,
        topics=topics,
        audit=audit,
        default=_default_site(settings),
    )
    await site.load()
    alarms = AlarmService(writer=writer, hub=hub, registry=registry, site=site)
    alarms.load(
        *await asyncio.gather(
            asyncio.to_thread(alarm_store.load_open, engine), asyncio.to_thread(alarm_store.load_rules, engine)
        )
    )
    legacy_commands = LegacyCommandRelay(publisher=bridge, registry=registry)
    holds = HoldService(registry=registry, publisher=bridge, topics=topics, writer=writer)
    leases = LeaseService(writer=writer, hub=hub, registry=registry, audit=audit, lapse_s=settings.lease_lapse_s)
    estop = EStopService(
        registry=registry,
        publisher=bridge,
        topics=topics,
        writer=writer,
        hub=hub,
        legacy=legacy_commands,
        audit=audit,
        signing_key=server_key(settings),
    )
    # the e-stop and the holds as last stored, before the broker link starts (the broker may have lost them)
    latches = await asyncio.to_thread(latch_store.load_latches, engine)
    for row in latches:
        if row["kind"] == latch_store.ESTOP:
            estop.restore(row)
    holds.restore([row for row in latches if row["kind"] == latch_store.HOLD])
    latch_sync = LatchSync(publisher=bridge, topics=topics, server_id=bridge.name, services=[estop, holds])
    commands = CommandService(
        registry=registry,
        publisher=bridge,
        topics=topics,
        writer=writer,
        hub=hub,
        ack_timeout_grace_s=settings.command_ack_timeout_grace_s,
        estop=estop,
        holds=holds,
        legacy=legacy_commands,
        leases=leases,
        audit=audit,
        site=site,
        alarms=alarms,
        poses=poses,
    )
    legacy = LegacyAdapter(registry=registry, ingest=ingest, rejects=rejects, relay=legacy_commands, holds=holds)
    runs = RunService(
        engine=engine,
        writer=writer,
        hub=hub,
        registry=registry,
        audit=audit,
        alarms=alarms,
        frames=FrameStore(root=settings.frames_root, quota_bytes=int(settings.runs_frames_quota_mb * 1024 * 1024)),
    )
    runs.load(await asyncio.to_thread(run_store.open_runs, engine))

    def record_frame(frame: Frame) -> None:
        runs.on_frame(frame)
        if foxglove is not None:
            foxglove.on_frame(frame)

    camera = CameraRelay(recorder=record_frame)
    repair = GapRepair(
        registry=registry, ingest=ingest, publisher=bridge, topics=topics, rejects=rejects, on_lost=alarms.data_lost
    )
    pose_publisher = PosePublisher(
        board=poses, publisher=bridge, topics=topics, server_id=bridge.name, acl_check_s=settings.poses_acl_check_s
    )
    forgetter = RobotForgetter(registry=registry, publisher=bridge, topics=topics, writer=writer, hub=hub)
    dispatcher = Dispatcher(
        topics=topics,
        registry=registry,
        ingest=ingest,
        commands=commands,
        estop=estop,
        rejects=rejects,
        legacy=legacy.handle if settings.legacy_enabled else None,
        camera=camera,
        is_own_clear=forgetter.is_own_clear,
        clock=ClockService(publisher=bridge, topics=topics),
        repair=repair,
        holds=holds,
        alarms=alarms,
        on_config=runs.on_agent_config,
        site=site,
        latches=latch_sync,
        poses=pose_publisher,
    )
    rollups = RollupWorker(
        engine=engine,
        raw_days=settings.retention_raw_days,
        agg_days=settings.retention_agg_days,
        interval_s=settings.retention_interval_s,
        rollup_interval_s=settings.rollup_interval_s,
        audit_days=settings.retention_audit_days,
    )
    missions = MissionService(
        writer=writer,
        hub=hub,
        registry=registry,
        commands=commands,
        estop=estop,
        site=ServedSite(site),
        alarms=alarms,
        engine=engine,
        server_id=bridge.name,
        leases=leases,
        runs=runs,
        # plans are CPU work: threads of their own, not the ones that serve database reads (core/workpool.py)
        planner=WorkPool("planner", workers=PLANNER_WORKERS, queue_max=PLANNER_QUEUE),
    )
    missions.load(await asyncio.to_thread(mission_store.load_missions, engine))
    readers = Readers(
        engine=create_reader_engine(settings),
        reads=settings.reader_pool_size,
        gate=ExportGate(
            max_total=settings.export_max_concurrent,
            max_per_client=settings.export_max_per_client,
            retry_after_s=settings.export_retry_after_s,
        ),
        stall_timeout_s=settings.export_stall_timeout_s,
        statement_timeout_s=settings.reader_statement_timeout_s,
    )
    services = Services(
        settings=settings,
        engine=engine,
        topics=topics,
        rejects=rejects,
        writer=writer,
        hub=hub,
        registry=registry,
        ingest=ingest,
        commands=commands,
        estop=estop,
        legacy=legacy,
        dispatcher=dispatcher,
        bridge=bridge,
        camera=camera,
        rollups=rollups,
        forgetter=forgetter,
        holds=holds,
        legacy_commands=legacy_commands,
        legacy_registrations=LegacyRegistrations(registry=registry, writer=writer, relay=legacy_commands),
        heartbeat=HeartbeatPublisher(publisher=bridge, topics=topics, server_id=bridge.name, legacy=legacy_commands),
        poses=pose_publisher,
        leases=leases,
        audit=audit,
        repair=repair,
        alarms=alarms,
        site=site,
        runs=runs,
        missions=missions,
        rehearsals=RehearsalService(missions=missions, registry=registry, site=site),
        readers=readers,
        foxglove=foxglove,
        latches=latch_sync,
        watchdog=LoopWatchdog(alarm_s=settings.loop_stall_alarm_s, on_alarm=partial(_loop_stalled, alarms)),
        passwords=WorkPool("passwords", workers=PASSWORD_WORKERS, queue_max=PASSWORD_QUEUE),
    )
    services.start(asyncio.get_running_loop())
    return services


def _loop_stalled(alarms: AlarmService, late_s: float) -> None:
    """The loop watchdog's alarm (on the loop, once it is back): fleet-wide, an event an operator acknowledges."""
    message = f"the server's event loop stalled for {late_s * 1000:.0f} ms (the log says where it was stuck)"
    alarms.raise_("", LOOP_STALL, message, {"stall_ms": round(late_s * 1000)})


def _foxglove(settings: Settings) -> FoxgloveLive | None:
    """The live Foxglove WebSocket server, when FLEET_FOXGLOVE_WS is on."""
    if not settings.foxglove_ws:
        return None
    try:
        return FoxgloveLive(host=settings.foxglove_ws_host, port=settings.foxglove_ws_port)
    except ImportError:
        raise ValueError(
            "FLEET_FOXGLOVE_WS is on but foxglove-sdk is not installed: pip install 'mollusca-fleet[foxglove]'"
        ) from None


def _default_site(settings: Settings) -> Site:
    """Version 1 of the site on the first start: FLEET_POOL_BOUNDARY, which must be a pool (a simple polygon),
    with the wall tags of FLEET_SITE_TAGS."""
    try:
        return Site(boundary=[[float(x), float(y)] for x, y in settings.pool_boundary], tags=settings.site_tags)
    except ValidationError as exc:
        raise ValueError(f"FLEET_POOL_BOUNDARY (pool_boundary) / FLEET_SITE_TAGS do not make a site: {exc}") from None


def _subscriptions(settings: Settings, topics: Topics) -> list[Subscription]:
    subscriptions = [
        Subscription(topics.all_status(), QOS_STATUS),
        Subscription(topics.all_acks(), QOS_ACK),
        Subscription(topics.estop(), QOS_ESTOP),
        Subscription(topics.all_holds(), QOS_HOLD),
        # after the e-stop and the holds: when our marker comes back, their retained messages came before it
        Subscription(topics.sync(), QOS_SYNC),
        Subscription(topics.all_camera(), 0),  # frames are only worth anything live: never queued for us
        Subscription(topics.all_repair_replies(), QOS_REPAIR),
        Subscription(topics.all_configs(), QOS_CONFIG),
        Subscription(topics.poses(), QOS_POSES),  # our own poses back: the broker's ACL lets them through
    ]
    group = settings.ingest_shared_group
    if group:  # replicas: stored once via the shared group, live copies (QoS 0) for this replica's clients
        subscriptions.append(Subscription(shared_subscription(group, topics.all_telemetry()), QOS_TELEMETRY, "store"))
        subscriptions.append(Subscription(topics.all_telemetry(), 0, "live"))
    else:
        subscriptions.append(Subscription(topics.all_telemetry(), QOS_TELEMETRY, "telemetry"))
    if settings.legacy_enabled:  # legacy seqs are assigned by the server: one replica handles each message
        legacy_filter = shared_subscription(group, LEGACY_SENSOR_FILTER) if group else LEGACY_SENSOR_FILTER
        subscriptions.append(Subscription(legacy_filter, 1))
    # clock sync: one replica answers each request
    time_requests = topics.all_time_requests()
    subscriptions.append(Subscription(shared_subscription(group, time_requests) if group else time_requests, QOS_TIME))
    return subscriptions
