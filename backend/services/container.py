"""Builds and tears down the server's services; the app keeps one instance on ``app.state.services``."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from dataclasses import dataclass, field

from sqlalchemy import Engine

from backend.comms.mqtt_bridge import InboundMessage, MqttBridge, Subscription
from backend.core.config import Settings
from backend.core.loopwatch import LoopWatchdog
from backend.core.rejects import RejectCounter
from backend.services.camera import CameraRelay
from backend.services.commands import CommandService
from backend.services.dispatcher import Dispatcher
from backend.services.estop import EStopService
from backend.services.hub import LiveHub
from backend.services.ingest import TelemetryIngest
from backend.services.legacy import LegacyAdapter
from backend.services.registry import Registry
from backend.services.retention import RetentionJob
from backend.store import repository as repo
from backend.store.db import create_db_engine, upgrade_to_head
from backend.store.writer import BatchWriter
from fleet_protocol import LEGACY_SENSOR_FILTER, QOS_ACK, QOS_ESTOP, QOS_STATUS, QOS_TELEMETRY, Topics

log = logging.getLogger(__name__)

TICK_S = 0.5


@dataclass
class Services:
    settings: Settings
    engine: Engine
    topics: Topics
    rejects: RejectCounter
    writer: BatchWriter
    hub: LiveHub
    registry: Registry
    ingest: TelemetryIngest
    commands: CommandService
    estop: EStopService
    legacy: LegacyAdapter
    dispatcher: Dispatcher
    bridge: MqttBridge
    ticker: asyncio.Task[None] | None = None
    camera: CameraRelay = field(default_factory=CameraRelay)
    retention: RetentionJob | None = None
    watchdog: LoopWatchdog = field(default_factory=LoopWatchdog)

    async def stop(self) -> None:
        self.watchdog.stop()
        if self.ticker is not None:
            self.ticker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self.ticker
        if self.retention is not None:
            await asyncio.to_thread(self.retention.stop)
        await self.bridge.stop()
        for st in self.registry.robots.values():  # persist last_seen of every robot
            if st.dirty:
                self.registry.persist(st)
        await asyncio.to_thread(self.writer.stop)
        self.engine.dispose()


async def _tick(services: Services) -> None:
    while True:
        await asyncio.sleep(TICK_S)
        try:
            now = time.time()
            services.registry.tick(now)
            services.commands.sweep(now)
        except Exception:
            log.exception("periodic tick failed")


async def build_services(settings: Settings) -> Services:
    topics = Topics(settings.topic_prefix)
    engine = create_db_engine(settings)
    await asyncio.to_thread(upgrade_to_head, engine)
    robots = await asyncio.to_thread(repo.load_robots, engine)

    writer = BatchWriter(
        engine, settings.writer_batch_rows, settings.writer_batch_interval_s, settings.writer_queue_max
    )
    writer.start()
    # Rejects land in the events table at the same (rate-limited) pace as the log.
    rejects = RejectCounter(
        on_logged=lambda d: writer.submit(repo.insert_event(time.time(), "reject", None, d))
    )
    hub = LiveHub(settings.ws_client_queue_max, settings.ws_flush_interval_s)
    registry = Registry(writer, hub, settings.stale_after_s, settings.legacy_offline_after_s)
    registry.load(robots)
    ingest = TelemetryIngest(registry, writer, hub, topics)

    subscriptions = [
        Subscription(topics.all_status(), QOS_STATUS),
        Subscription(topics.all_acks(), QOS_ACK),
        Subscription(topics.estop(), QOS_ESTOP),
        Subscription(topics.all_camera(), 0),  # frames are only worth anything live: never queued for us
    ]
    group = settings.ingest_shared_group
    if group:  # replicas: stored once via the shared group, live copies (QoS 0) for this replica's clients
        subscriptions.append(Subscription(f"$share/{group}/{topics.all_telemetry()}", QOS_TELEMETRY, "store"))
        subscriptions.append(Subscription(topics.all_telemetry(), 0, "live"))
    else:
        subscriptions.append(Subscription(topics.all_telemetry(), QOS_TELEMETRY, "telemetry"))
    if settings.legacy_enabled:  # legacy seqs are assigned by the server: one replica handles each message
        legacy_filter = f"$share/{group}/{LEGACY_SENSOR_FILTER}" if group else LEGACY_SENSOR_FILTER
        subscriptions.append(Subscription(legacy_filter, 1))

    dispatcher: Dispatcher | None = None

    def on_messages(batch: list[InboundMessage]) -> None:
        assert dispatcher is not None
        dispatcher.handle_batch(batch)

    bridge = MqttBridge(
        settings.mqtt_url,
        subscriptions,
        on_messages,
        client_id=settings.mqtt_client_id,
        keepalive=settings.mqtt_keepalive_s,
        queue_max=settings.inbound_queue_max,
        protocol=settings.mqtt_protocol,
        session_expiry_s=settings.mqtt_session_expiry_s,
        receive_maximum=settings.mqtt_receive_maximum,
        on_store=ingest.store_batch,
        credentials=settings.mqtt_credentials,
    )
    # Broker acks follow the DB commit of what each message caused (see store/writer.py).
    ingest.buffered = True
    bridge.on_ack_marker = ingest.drained
    writer.on_acks = bridge.ack
    if group:
        ingest.stored_via_shared = lambda: bridge.v5
    commands = CommandService(registry, bridge, topics, writer, hub, settings.command_ack_timeout_grace_s)
    estop = EStopService(registry, bridge, topics, writer, hub)
    legacy = LegacyAdapter(registry, ingest, rejects)
    camera = CameraRelay()
    dispatcher = Dispatcher(
        topics,
        registry,
        ingest,
        commands,
        estop,
        rejects,
        legacy.handle if settings.legacy_enabled else None,
        camera=camera,
    )
    services = Services(
        settings,
        engine,
        topics,
        rejects,
        writer,
        hub,
        registry,
        ingest,
        commands,
        estop,
        legacy,
        dispatcher,
        bridge,
        camera=camera,
    )
    services.retention = RetentionJob(
        engine,
        settings.retention_raw_days,
        settings.retention_agg_days,
        settings.retention_interval_s,
        rollup_interval_s=settings.rollup_interval_s,
    )
    services.retention.start()
    bridge.start(asyncio.get_running_loop())
    services.watchdog.start(asyncio.get_running_loop())
    services.ticker = asyncio.create_task(_tick(services), name="fleet-tick")
    return services
