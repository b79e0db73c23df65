"""Routes batches of inbound MQTT messages (on the event loop) to the services.

Every malformed message is counted per reason, logged at a rate-limited WARNING and dropped; one bad
message never stops the batch or the bridge.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from backend.comms.base import InboundMessage
from backend.core.rejects import InboundRejects
from backend.services.control.commands import CommandService
from backend.services.fleet.clock import ClockService
from backend.services.fleet.poses import PosePublisher
from backend.services.fleet.registry import Registry
from backend.services.live.camera import CameraRelay
from backend.services.safety.alarm_checks import ALARM_STREAMS
from backend.services.safety.alarms import AlarmService
from backend.services.safety.estop import EStopService
from backend.services.safety.holds import HoldService
from backend.services.safety.latches import LatchSync
from backend.services.site.service import SiteService
from backend.services.telemetry.ingest import TelemetryIngest
from backend.services.telemetry.repair import GapRepair
from fleet_protocol import (
    AgentConfig,
    ProtocolError,
    TopicKind,
    Topics,
    decode_ack,
    decode_agent_config,
    decode_estop,
    decode_hold,
    decode_status,
    decode_sync,
    decode_telemetry,
    is_legacy_topic,
)

log = logging.getLogger(__name__)


class Dispatcher:
    def __init__(
        self,
        topics: Topics,
        registry: Registry,
        ingest: TelemetryIngest,
        commands: CommandService,
        estop: EStopService,
        rejects: InboundRejects,
        legacy: Callable[[InboundMessage], None] | None = None,
        camera: CameraRelay | None = None,
        clock: ClockService | None = None,
        repair: GapRepair | None = None,
        is_own_clear: Callable[[str, bytes], bool] | None = None,
        *,
        holds: HoldService,
        alarms: AlarmService | None = None,
        on_config: Callable[[str, AgentConfig | None, float], None] | None = None,
        site: SiteService | None = None,
        latches: LatchSync | None = None,
        poses: PosePublisher | None = None,
    ) -> None:
        self._poses = poses
        self._latches = latches
        self._site = site
        self._on_config = on_config
        self._alarms = alarms
        self._holds = holds
        self._repair = repair
        self._camera = camera
        self._clock = clock
        #: the echo of a retained message this server cleared (forgetting a robot): not a reject
        self._is_own_clear = is_own_clear
        self._topics = topics
        self._registry = registry
        self._ingest = ingest
        self._commands = commands
        self._estop = estop
        self._rejects = rejects
        self._legacy = legacy

    def connection_changed(self, connected: bool) -> None:
        """Each (re)connection to the broker publishes the site again (retained: a broker restarted empty)
        and checks that the broker still holds the e-stop and the holds (safety/latches.py)."""
        if self._site is not None:
            self._site.on_connection_change(connected)
        if self._latches is not None:
            self._latches.on_connection_change(connected)
        if self._poses is not None:  # the ACL check: our own poses must come back soon
            self._poses.on_connection_change(connected)

    def handle_batch(self, batch: list[InboundMessage]) -> None:
        for msg in batch:
            kind = "unknown"
            try:
                if is_legacy_topic(msg.topic) and self._legacy is not None:
                    kind = "legacy"
                    self._legacy(msg)
                    continue
                parsed = self._topics.parse(msg.topic)
                kind = parsed.kind.value
                self._route(parsed.kind, parsed.robot_id, parsed.stream, msg)
            except ProtocolError as exc:
                self._rejects.reject(kind, exc.reason, msg.topic, exc.detail)
            except Exception as exc:
                log.exception("error handling message on %s", msg.topic[:120])
                self._rejects.reject(kind, "internal_error", msg.topic, repr(exc))

    def _route(self, kind: TopicKind, robot_id: str | None, stream: str | None, msg: InboundMessage) -> None:
        if kind is TopicKind.TELEMETRY:
            assert robot_id is not None and stream is not None
            if self._is_own_clear is not None and self._is_own_clear(msg.topic, msg.payload):
                return
            t = decode_telemetry(msg.payload, stream)
            self._ingest.ingest(robot_id, stream, t.ts, t.seq, t.data, msg.received)
            if self._repair is not None:
                self._repair.observe(robot_id, stream, t.boot, t.seq, msg.received)
            if self._alarms is not None and stream in ALARM_STREAMS:
                self._alarms.on_telemetry(robot_id, stream, t.ts, t.data)
        elif kind is TopicKind.STATUS:
            assert robot_id is not None
            if not msg.payload:
                return  # a retained status being cleared: nothing to apply
            status = decode_status(msg.payload)
            self._registry.apply_status(robot_id, status, msg.received, msg.retain)
            if self._repair is not None:
                self._repair.robot_status(robot_id, status.online, msg.retain)
        elif kind is TopicKind.ACK:
            assert robot_id is not None
            ack = decode_ack(msg.payload)
            st = self._registry.get(robot_id)
            if st is not None:
                self._registry.touch(st, msg.received)
            if self._estop.owns_ack(ack.id):
                self._estop.on_ack(robot_id, ack, msg.received)
            else:
                try:
                    self._commands.on_ack(robot_id, ack, msg.received)
                except ValueError as exc:
                    raise ProtocolError("ack_robot_mismatch", str(exc)) from None
        elif kind is TopicKind.CAMERA:
            assert robot_id is not None
            if self._camera is None:
                raise ProtocolError("unexpected_topic", msg.topic[:120])
            self._camera.on_frame(robot_id, msg.payload, msg.received)
            st = self._registry.get(robot_id)
            if st is not None:
                self._registry.touch(st, msg.received)  # frames count as signs of life
        elif kind is TopicKind.REPAIR_REPLY and self._repair is not None:
            assert robot_id is not None
            self._repair.on_reply(robot_id, msg.payload, msg.received)
        elif kind is TopicKind.ESTOP:
            self._estop.on_estop(decode_estop(msg.payload))
        elif kind is TopicKind.HOLD:
            assert robot_id is not None
            self._holds.on_hold(robot_id, decode_hold(msg.payload))
        elif kind is TopicKind.SYNC and self._latches is not None:
            self._latches.on_marker(decode_sync(msg.payload))
        elif kind is TopicKind.POSES and self._poses is not None:
            self._poses.on_poses(msg.payload)
        elif kind is TopicKind.CONFIG and self._on_config is not None:
            assert robot_id is not None
            self._on_config(robot_id, decode_agent_config(msg.payload), msg.received)
        elif kind is TopicKind.TIME_REQ and self._clock is not None:
            assert robot_id is not None
            self._clock.on_request(robot_id, msg.payload, msg.received)
        else:
            raise ProtocolError("unexpected_topic", msg.topic[:120])
