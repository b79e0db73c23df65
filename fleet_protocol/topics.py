"""Topic names: built and parsed under one prefix, in exactly one place (:class:`Topics`)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import StrEnum

from fleet_protocol.core import _PREFIX_RE, DEFAULT_PREFIX, ProtocolError, is_valid_robot_id, is_valid_stream


class TopicKind(StrEnum):
    STATUS = "status"
    TELEMETRY = "telemetry"
    CMD = "cmd"
    ACK = "ack"
    CAMERA = "camera"
    ESTOP = "estop"
    HEARTBEAT = "heartbeat"
    HOLD = "hold"
    TIME_REQ = "time/req"
    TIME_RESP = "time/resp"
    REPAIR_REQUEST = "repair_request"
    REPAIR_REPLY = "repair_reply"
    SITE = "site"
    CONFIG = "config"
    SYNC = "sync"
    POSES = "poses"


@dataclass(frozen=True, slots=True)
class ParsedTopic:
    kind: TopicKind
    robot_id: str | None = None
    stream: str | None = None


class Topics:
    """Builds and parses topic names under one prefix. The only place the prefix is applied."""

    def __init__(self, prefix: str = DEFAULT_PREFIX) -> None:
        prefix = prefix.strip("/")
        if not _PREFIX_RE.match(prefix):
            raise ValueError(f"invalid topic prefix {prefix!r}")
        self.prefix = prefix
        self._prefix_parts = len(prefix.split("/"))

    def _robot(self, robot_id: str, *rest: str) -> str:
        if not is_valid_robot_id(robot_id):
            raise ProtocolError("bad_robot_id", robot_id[:80])
        return "/".join((self.prefix, robot_id, *rest))

    # -- concrete topics
    def status(self, robot_id: str) -> str:
        return self._robot(robot_id, "status")

    def telemetry(self, robot_id: str, stream: str) -> str:
        if not is_valid_stream(stream):
            raise ProtocolError("bad_stream", stream[:80])
        return self._robot(robot_id, "telemetry", stream)

    def cmd(self, robot_id: str) -> str:
        return self._robot(robot_id, "cmd")

    def ack(self, robot_id: str) -> str:
        return self._robot(robot_id, "ack")

    def camera(self, robot_id: str) -> str:
        return self._robot(robot_id, "camera")

    def config(self, robot_id: str) -> str:
        """The agent's effective configuration (:class:`AgentConfig`, secrets removed), retained; only that
        robot writes it."""
        return self._robot(robot_id, "config")

    def ping(self, robot_id: str) -> str:
        """The agent's own link probe: it publishes here (QoS 0) and listens to itself while driving."""
        return self._robot(robot_id, "ping")

    def estop(self) -> str:
        return f"{self.prefix}/estop"

    def heartbeat(self) -> str:
        """Every server replica's heartbeat (:class:`ServerHeartbeat`, server id in the payload)."""
        return f"{self.prefix}/heartbeat"

    def hold(self, robot_id: str) -> str:
        """A robot's stop latch (:class:`RobotHold`), retained; written by the server only."""
        return self._robot(robot_id, "hold")

    def site(self) -> str:
        """The site (:class:`fleet_protocol.motion.SiteMessage`), retained; written by the server only."""
        return f"{self.prefix}/site"

    def poses(self) -> str:
        """The fleet's latest poses (:class:`fleet_protocol.neighbours.FleetPoses`), QoS 0; servers write,
        every robot reads."""
        return f"{self.prefix}/poses"

    def sync(self) -> str:
        """A server's marker to itself after each (re)connection (:class:`ServerSync`); servers only."""
        return f"{self.prefix}/sync"

    def all_holds(self) -> str:
        return f"{self.prefix}/+/hold"

    def time_req(self, robot_id: str) -> str:
        """Clock sync: the robot asks the server's time here (fleet_protocol.clock)."""
        return self._robot(robot_id, "time", "req")

    def time_resp(self, robot_id: str) -> str:
        """Clock sync: the server answers here; only the server writes it."""
        return self._robot(robot_id, "time", "resp")

    def all_time_requests(self) -> str:
        return f"{self.prefix}/+/time/req"

    def repair_request(self, robot_id: str) -> str:
        """Server -> robot: "send me these seq ranges again" (fleet_protocol.repair)."""
        return self._robot(robot_id, "repair", "request")

    def repair_reply(self, robot_id: str) -> str:
        """Robot -> server: the replayed messages, and the ranges it no longer has."""
        return self._robot(robot_id, "repair", "reply")

    # -- subscription filters
    def all_status(self) -> str:
        return f"{self.prefix}/+/status"

    def all_telemetry(self) -> str:
        return f"{self.prefix}/+/telemetry/+"

    def all_acks(self) -> str:
        return f"{self.prefix}/+/ack"

    def all_configs(self) -> str:
        return f"{self.prefix}/+/config"

    def all_camera(self) -> str:
        return f"{self.prefix}/+/camera"

    def all_repair_replies(self) -> str:
        return f"{self.prefix}/+/repair/reply"

    def parse(self, topic: str) -> ParsedTopic:
        """Classify an incoming topic; raises :class:`ProtocolError` for anything not ours or malformed."""
        parts = topic.split("/")
        n = self._prefix_parts
        if "/".join(parts[:n]) != self.prefix:
            raise ProtocolError("foreign_topic", topic[:120])
        rest = parts[n:]
        if rest == ["estop"]:
            return ParsedTopic(TopicKind.ESTOP)
        if rest == ["heartbeat"]:
            return ParsedTopic(TopicKind.HEARTBEAT)
        if rest == ["site"]:
            return ParsedTopic(TopicKind.SITE)
        if rest == ["sync"]:
            return ParsedTopic(TopicKind.SYNC)
        if rest == ["poses"]:
            return ParsedTopic(TopicKind.POSES)
        if len(rest) < 2:
            raise ProtocolError("bad_topic", topic[:120])
        robot_id = rest[0]
        if not is_valid_robot_id(robot_id):
            raise ProtocolError("bad_robot_id", robot_id[:80])
        kind = rest[1]
        if kind == "telemetry" and len(rest) == 3:
            if not is_valid_stream(rest[2]):
                raise ProtocolError("bad_stream", rest[2][:80])
            return ParsedTopic(TopicKind.TELEMETRY, robot_id, rest[2])
        if kind == "repair" and len(rest) == 3 and rest[2] in ("request", "reply"):
            return ParsedTopic(TopicKind(f"repair_{rest[2]}"), robot_id)
        if len(rest) == 2 and kind in ("status", "cmd", "ack", "camera", "hold", "config"):
            return ParsedTopic(TopicKind(kind), robot_id)
        if len(rest) == 3 and kind == "time" and rest[2] in ("req", "resp"):
            return ParsedTopic(TopicKind(f"time/{rest[2]}"), robot_id)
        raise ProtocolError("bad_topic", topic[:120])


def shared_subscription(group: str, topic_filter: str) -> str:
    """``$share/<group>/<filter>``: an MQTT v5 shared subscription (the broker hands each message to one
    subscriber of the group: replicas store every message once)."""
    if not _SHARE_GROUP_RE.match(group):
        raise ValueError(f"invalid shared-subscription group {group!r}")
    return f"$share/{group}/{topic_filter}"


_SHARE_GROUP_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
