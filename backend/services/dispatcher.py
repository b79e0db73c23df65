"""Routes batches of inbound MQTT messages (on the event loop) to the services.

Every malformed message is counted per reason, logged at a rate-limited WARNING and dropped; one bad
message never stops the batch or the bridge.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from backend.comms.mqtt_bridge import InboundMessage
from backend.core.rejects import RejectCounter
from backend.services.camera import CameraRelay
from backend.services.commands import CommandService
from backend.services.estop import EStopService
from backend.services.ingest import TelemetryIngest
from backend.services.registry import Registry
from fleet_protocol import (
    ProtocolError,
    TopicKind,
    Topics,
    decode_ack,
    decode_estop,
    decode_status,
    decode_telemetry,
)

log = logging.getLogger(__name__)

LEGACY_PREFIX = "robot/"


class Dispatcher:
    def __init__(
        self,
        topics: Topics,
        registry: Registry,
        ingest: TelemetryIngest,
        commands: CommandService,
        estop: EStopService,
        rejects: RejectCounter,
        legacy: Callable[[InboundMessage], None] | None = None,
        camera: CameraRelay | None = None,
    ) -> None:
        self._camera = camera
        self._topics = topics
        self._registry = registry
        self._ingest = ingest
        self._commands = commands
        self._estop = estop
        self._rejects = rejects
        self._legacy = legacy

    def handle_batch(self, batch: list[InboundMessage]) -> None:
        for msg in batch:
            kind = "unknown"
            try:
                if msg.topic.startswith(LEGACY_PREFIX) and self._legacy is not None:
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
            t = decode_telemetry(msg.payload, stream)
            self._ingest.ingest(robot_id, stream, t.ts, t.seq, t.data, msg.received)
        elif kind is TopicKind.STATUS:
            assert robot_id is not None
            if not msg.payload:
                return  # a retained status being cleared: nothing to apply
            self._registry.apply_status(robot_id, decode_status(msg.payload), msg.received, msg.retain)
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
        elif kind is TopicKind.ESTOP:
            self._estop.on_estop(decode_estop(msg.payload))
        else:
            raise ProtocolError("unexpected_topic", msg.topic[:120])
