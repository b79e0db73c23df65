"""The server's services as one running set: what the app and the API reach (``app.state.services``),
started and stopped together in order, and the periodic tick that ages the fleet's state. Built by
container.py."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from dataclasses import dataclass, field

from sqlalchemy import Engine

from backend.comms.base import Communicator
from backend.core.config import Settings
from backend.core.loopwatch import LoopWatchdog
from backend.core.rejects import InboundRejects
from backend.core.workpool import WorkPool
from backend.services.access.audit import AuditService
from backend.services.control.commands import CommandService
from backend.services.control.leases import LeaseService
from backend.services.dispatcher import Dispatcher
from backend.services.fleet.forget import RobotForgetter
from backend.services.fleet.heartbeat import HeartbeatPublisher
from backend.services.fleet.poses import PosePublisher
from backend.services.fleet.registry import Registry
from backend.services.legacy.bridge import LegacyAdapter
from backend.services.legacy.registrations import LegacyRegistrations
from backend.services.legacy.relay import LegacyCommandRelay
from backend.services.live.camera import CameraRelay
from backend.services.live.foxglove import FoxgloveLive
from backend.services.live.hub import LiveHub
from backend.services.missions.service import MissionService
from backend.services.rehearsal import RehearsalService
from backend.services.runs.recorder import RunService
from backend.services.safety.alarms import AlarmService
from backend.services.safety.estop import EStopService
from backend.services.safety.holds import HoldService
from backend.services.safety.latches import LatchSync
from backend.services.site.service import SiteService
from backend.services.telemetry.ingest import TelemetryIngest
from backend.services.telemetry.readers import Readers
from backend.services.telemetry.repair import GapRepair
from backend.services.telemetry.rollups import RollupWorker
from backend.store.writer import BatchWriter
from fleet_protocol import Topics

log = logging.getLogger(__name__)

TICK_S = 0.5


@dataclass(kw_only=True)
class Services:
    settings: Settings
    engine: Engine
    topics: Topics
    rejects: InboundRejects
    writer: BatchWriter
    hub: LiveHub
    registry: Registry
    ingest: TelemetryIngest
    commands: CommandService
    estop: EStopService
    legacy: LegacyAdapter
    dispatcher: Dispatcher
    bridge: Communicator  # the MQTT bridge, as the services and the API see it
    camera: CameraRelay
    #: the rollups and the retention of raw and aggregate rows (a thread of its own)
    rollups: RollupWorker
    forgetter: RobotForgetter
    holds: HoldService
    legacy_commands: LegacyCommandRelay
    #: which robots may speak on the old framework's topics (an admin names them)
    legacy_registrations: LegacyRegistrations
    heartbeat: HeartbeatPublisher
    #: the fleet's poses, ten times a second (fleet/poses.py); its board is what the goto check reads
    poses: PosePublisher | None = None
    leases: LeaseService
    audit: AuditService
    repair: GapRepair
    alarms: AlarmService
    site: SiteService
    runs: RunService
    missions: MissionService
    rehearsals: RehearsalService
    #: history reads and exports: their own database pool, threads and admission
    readers: Readers
    watchdog: LoopWatchdog = field(default_factory=LoopWatchdog)
    #: password checks (scrypt) for logins and password changes: threads of their own (core/workpool.py)
    passwords: WorkPool = field(default_factory=lambda: WorkPool("passwords", workers=1, queue_max=8))
    ticker: asyncio.Task[None] | None = None
    beating: asyncio.Task[None] | None = None
    posing: asyncio.Task[None] | None = None
    missions_task: asyncio.Task[None] | None = None
    #: the live Foxglove WebSocket server (FLEET_FOXGLOVE_WS), None when off
    foxglove: FoxgloveLive | None = None
    #: puts the e-stop and holds back on a broker that lost them, at each (re)connection
    latches: LatchSync | None = None

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """Start the background parts: rollups/retention, the broker link, the loop watchdog, the tick and the
        heartbeat and the fleet poses."""
        self.rollups.start()
        self.runs.frames.start()
        self.bridge.start(loop)
        self.watchdog.start(loop)
        self.ticker = loop.create_task(_tick(self), name="fleet-tick")
        self.beating = loop.create_task(self.heartbeat.run(), name="fleet-heartbeat")
        if self.poses is not None:
            self.posing = loop.create_task(self.poses.run(), name="fleet-poses")
        self.missions_task = loop.create_task(self.missions.run(), name="fleet-missions")

    async def stop(self) -> None:
        self.watchdog.stop()
        for task in (self.ticker, self.beating, self.posing, self.missions_task):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        await self.missions.close()  # formation missions' fast loops (their robots stop on the deadman)
        self.rehearsals.close()
        # A clean DISCONNECT suppresses the Last Will: robots on the old framework hear "stop" from us.
        self.legacy_commands.stop_all("server shutting down")
        self.legacy_commands.close()
        await asyncio.to_thread(self.rollups.stop)
        await self.site.close()
        await asyncio.to_thread(self.runs.frames.stop)
        if self.foxglove is not None:
            await asyncio.to_thread(self.foxglove.stop)
        await self.bridge.stop()
        for st in self.registry.robots.values():  # persist last_seen of every robot
            if st.dirty:
                self.registry.persist(st)
        await asyncio.to_thread(self.passwords.close)
        await asyncio.to_thread(self.writer.stop)
        self.readers.close()
        self.engine.dispose()


async def _tick(services: Services) -> None:
    while True:
        await asyncio.sleep(TICK_S)
        try:
            now = time.time()
            services.registry.tick(now)
            services.commands.sweep(now)
            services.repair.tick(now)
            services.alarms.tick(now)
            await services.leases.renew_goals(now, services.commands.running)
            services.leases.sync(now)
            services.alarms.sync(now)
            services.legacy_registrations.sync(now)
        except Exception:
            log.exception("periodic tick failed")
