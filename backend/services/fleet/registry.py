"""Robot registry: every robot's live state in memory, persisted to the robots table.

Online/offline comes from the retained status topic (and the agent's Last Will); legacy robots are
online while they publish. ``stale`` = online but no telemetry for ``stale_after_s``.

A robot whose status announces its keepalive is also shown offline ("link-silent") after 1.5 x that
without any message from it: the agent publishes at least every half keepalive, and the broker's Last
Will can come seconds later (Mosquitto 2.0 checks keepalives only every ~5 s). Its next message shows it
online again (the link came back before the broker gave up on it).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any

from backend.models import Robot
from backend.schemas import (
    CapabilitiesPublic,
    HoldPublic,
    LeasePublic,
    PositionPublic,
    RobotPublic,
    SensorStatePublic,
    StreamStats,
)
from backend.services.fleet.readiness import not_ready
from backend.services.live.hub import LiveHub
from backend.store import repository as repo
from backend.store.writer import BatchWriter
from fleet_protocol import (
    LEGACY_LISTENS_ON_DEFAULT,
    AgentConfig,
    LegacyListensOn,
    RobotHold,
    Status,
)

log = logging.getLogger(__name__)

RATE_WINDOW_S = 5
#: readiness: a position fix this recent, a clock this close to the server's
#: A robot is shown offline after this many keepalives without a message (MQTT's own 1.5).
LINK_SILENCE_FACTOR = 1.5
#: last_seen alone is persisted at most this often per robot (state changes are persisted at once).
PERSIST_EVERY_S = 5.0


@dataclass
class StreamState:
    last_seq: int | None = None
    last_ts: float | None = None
    gaps: int = 0
    out_of_order: int = 0
    restarts: int = 0
    #: messages received on this stream since the server started
    count: int = 0

    def observe(self, seq: int, ts: float) -> None:
        self.count += 1
        last = self.last_seq
        if last is None or seq == last + 1:
            pass
        elif seq > last + 1:
            self.gaps += seq - last - 1
        elif seq == 0 and last > 0 and (self.last_ts is None or ts > self.last_ts):
            self.restarts += 1  # the agent restarted and counts from zero again
        else:
            self.out_of_order += 1
            return
        self.last_seq = seq
        self.last_ts = ts


@dataclass
class RobotState:
    id: str
    first_seen: float
    legacy: bool = False
    online: bool = False
    agent_version: str = ""
    capabilities: CapabilitiesPublic = field(default_factory=CapabilitiesPublic)
    sensors: dict[str, SensorStatePublic] = field(default_factory=dict)
    estop: bool = False
    last_seen: float | None = None
    last_telemetry: float | None = None  # server clock
    position: PositionPublic | None = None
    streams: dict[str, StreamState] = field(default_factory=dict)
    #: latest message of slow, retained streams (e.g. lighthouse_geometry): a new live client gets them
    #: with its snapshot, as the robot published them only once
    retained: dict[str, tuple[float, int, dict[str, Any]]] = field(default_factory=dict)
    rate_buckets: dict[int, int] = field(default_factory=dict)
    stale_reported: bool = False
    #: from the robot's status; None (older agents, legacy robots): only the Last Will says offline
    keepalive_s: float | None = None
    #: from the robot's status: its agent runs the safety filter (others may count on it to take its half)
    collision_filter: bool = False
    #: shown offline by the link-silence check, not by the robot or its Last Will
    silenced: bool = False
    #: server clock of the last message from it of any kind (a retained replay counts: it restarts the
    #: silence window, e.g. after the server's own reconnect)
    last_heard: float | None = None
    dirty: bool = False
    persisted_at: float = 0.0
    #: robots on the old framework: the command topic it listens on (see fleet_protocol)
    legacy_listens_on: LegacyListensOn = LEGACY_LISTENS_ON_DEFAULT
    #: "hold this robot" (safety/holds.py), None when not held
    hold: RobotHold | None = None
    #: the control lease (control/leases.py keeps it here), None when nobody drives it
    lease: LeasePublic | None = None
    #: server clock when it last came online (rate rules wait for a full window after it)
    online_since: float | None = None
    #: the protocol version its status announced (None: an agent too old to say)
    protocol_version: int | None = None
    #: the latest ``health`` sample (safety/alarms.py keeps it here)
    health: dict[str, Any] | None = None
    #: its open alarms, kind -> severity (safety/alarms.py keeps it here)
    alarm_kinds: dict[str, str] = field(default_factory=dict)
    #: the effective configuration it published (fleet_protocol.AgentConfig, secrets removed; None: none yet)
    config: dict[str, Any] | None = None

    def msg_rate(self, now: float) -> float:
        current = int(now)
        total = sum(n for sec, n in self.rate_buckets.items() if current - sec < RATE_WINDOW_S)
        return round(total / RATE_WINDOW_S, 2)

    def is_stale(self, now: float, stale_after_s: float) -> bool:
        if not self.online:
            return False
        ref = self.last_telemetry if self.last_telemetry is not None else self.last_seen
        return ref is None or now - ref > stale_after_s


class Registry:
    def __init__(
        self,
        writer: BatchWriter,
        hub: LiveHub,
        stale_after_s: float = 2.0,
        legacy_offline_after_s: float = 10.0,
    ) -> None:
        self._writer = writer
        self._hub = hub
        self._stale_after = stale_after_s
        self._legacy_offline_after = legacy_offline_after_s
        self.robots: dict[str, RobotState] = {}

    def load(self, rows: list[Robot]) -> None:
        """Known robots start offline: their retained status (re)sets the truth within moments."""
        for r in rows:
            caps = CapabilitiesPublic.model_validate(r.capabilities or {})
            self.robots[r.id] = RobotState(
                id=r.id,
                first_seen=r.first_seen,
                legacy=r.legacy,
                online=False,
                agent_version=r.agent_version,
                capabilities=caps,
                last_seen=r.last_seen,
                legacy_listens_on="own" if r.legacy_listens_on == "own" else "shared",
            )

    def get(self, robot_id: str) -> RobotState | None:
        return self.robots.get(robot_id)

    def apply_config(self, robot_id: str, config: AgentConfig | None, received: float) -> RobotState | None:
        """Keep the agent's published configuration (None: its retained config was cleared). A config of a
        robot never seen creates no robot: its status does that."""
        st = self.robots.get(robot_id)
        if st is None:
            return None
        if config is None:
            st.config = None
        else:
            st.config = {**config.model_dump(mode="json"), "received": received}
        return st

    def forget(self, robot_id: str) -> RobotState | None:
        """Drop the robot from memory (its database row is the caller's: RobotForgetter)."""
        return self.robots.pop(robot_id, None)

    def public(self, st: RobotState, now: float | None = None) -> RobotPublic:
        now = time.time() if now is None else now
        return RobotPublic(
            id=st.id,
            online=st.online,
            last_seen=st.last_seen,
            stale=st.is_stale(now, self._stale_after),
            agent_version=st.agent_version,
            legacy=st.legacy,
            estop=st.estop,
            capabilities=st.capabilities,
            sensors=st.sensors,
            position=st.position,
            msg_rate=st.msg_rate(now),
            legacy_listens_on=st.legacy_listens_on if st.legacy else None,
            legacy_unit=self.legacy_unit(st),
            hold=HoldPublic(**st.hold.model_dump()) if st.hold is not None else None,
            lease=st.lease if st.lease is not None and now - st.lease.last_drive <= st.lease.lapse_s else None,
            ready=not (reasons := self.not_ready(st, now)),
            not_ready_reasons=reasons,
            alarms=dict(st.alarm_kinds),
        )

    #: the readiness rule (backend/services/fleet/readiness.py), shared with a mission's start
    not_ready = staticmethod(not_ready)

    def legacy_unit(self, st: RobotState) -> list[str]:
        """The legacy robots one drive to ``st`` moves: every robot on the shared topic (seed's code)."""
        if not st.legacy or st.legacy_listens_on == "own":
            return [st.id] if st.legacy else []
        return sorted(r.id for r in self.robots.values() if r.legacy and r.legacy_listens_on == "shared")

    def all_public(self, robot_ids: frozenset[str] | None = None) -> list[RobotPublic]:
        now = time.time()
        return [
            self.public(st, now) for rid, st in sorted(self.robots.items()) if robot_ids is None or rid in robot_ids
        ]

    def stream_stats(self, robot_id: str) -> dict[str, StreamState]:
        st = self.robots.get(robot_id)
        return dict(st.streams) if st else {}

    def merge_stream_stats(self, robot_id: str, stats: list[StreamStats]) -> list[StreamStats]:
        live = self.stream_stats(robot_id)
        for s in stats:
            ss = live.get(s.stream)
            if ss is not None:
                s.last_seq, s.gaps, s.out_of_order, s.restarts = (
                    ss.last_seq,
                    ss.gaps,
                    ss.out_of_order,
                    ss.restarts,
                )
        return stats

    # -- updates (event loop) --------------------------------------------------------------------------
    def ensure(self, robot_id: str, received: float) -> RobotState:
        """The robot's state, made when first heard of. Never legacy: only an admin's registration makes a
        robot one of the old framework (legacy/registrations.py)."""
        st = self.robots.get(robot_id)
        if st is None:
            st = self.robots[robot_id] = RobotState(id=robot_id, first_seen=received)
            st.dirty = True
            log.info("new robot %s", robot_id, extra={"robot_id": robot_id})
        return st

    def apply_status(self, robot_id: str, status: Status, received: float, retained: bool = False) -> None:
        """``retained``: replayed by the broker on subscribe, so the robot was last seen when it sent it."""
        st = self.ensure(robot_id, received)
        was_online = st.online
        if status.online and not was_online and st.legacy:
            log.warning(
                "robot %s speaks the agent's protocol but is registered as on the old framework: drives go to "
                "the old topics until an admin removes its registration (fleet-server robots legacy-remove)",
                robot_id,
                extra={"robot_id": robot_id},
            )
        st.online = status.online
        st.silenced = False
        st.estop = status.estop
        st.keepalive_s = status.keepalive_s
        st.collision_filter = status.collision_filter
        st.last_heard = received
        if status.agent_version:
            st.agent_version = status.agent_version
        if status.online:
            st.capabilities = CapabilitiesPublic(
                sensors=list(status.capabilities.sensors), commands=list(status.capabilities.commands)
            )
            previous = st.sensors
            st.sensors = {k: SensorStatePublic(**v.model_dump()) for k, v in status.sensors.items()}
            for name, state in st.sensors.items():  # sensor failures and recoveries go to the timeline
                before = previous.get(name)
                was_ok = before.ok if before is not None else True
                if state.ok != was_ok:
                    kind = "sensor_recovered" if state.ok else "sensor_failed"
                    self.event(kind, robot_id, {"sensor": name, "error": state.error or ""}, received)
        seen = min(status.ts, received) if retained else received
        st.last_seen = seen if st.last_seen is None else max(st.last_seen, seen)
        st.protocol_version = getattr(status, "protocol_version", None)
        if status.online and not was_online:
            st.online_since = received
            st.last_telemetry = received  # not stale before the first telemetry had a chance to arrive
        if was_online != status.online:
            self.event("online" if status.online else "offline", robot_id, {"source": "status"}, received)
        self.persist(st)
        self.push(st)

    def set_online(self, st: RobotState, online: bool, received: float, source: str) -> None:
        if st.online == online:
            return
        st.online = online
        st.online_since = received if online else None
        if online:
            st.last_telemetry = received
        self.event("online" if online else "offline", st.id, {"source": source}, received)
        self.persist(st)
        self.push(st)

    def touch(self, st: RobotState, received: float) -> None:
        st.last_seen = received
        st.dirty = True
        self._heard(st, received)

    def _heard(self, st: RobotState, received: float) -> None:
        """Restarts the silence window; a robot the link-silence check had shown offline is back."""
        st.last_heard = received
        if st.silenced:
            st.silenced = False
            self.set_online(st, True, received, "link-restored")

    def record_telemetry(
        self, st: RobotState, stream: str, seq: int, ts: float, data: dict[str, Any], received: float
    ) -> None:
        st.last_seen = received
        st.last_telemetry = received
        st.dirty = True
        self._heard(st, received)
        sec = int(received)
        st.rate_buckets[sec] = st.rate_buckets.get(sec, 0) + 1
        if len(st.rate_buckets) > RATE_WINDOW_S + 2:
            for old in [s for s in st.rate_buckets if sec - s >= RATE_WINDOW_S]:
                del st.rate_buckets[old]
        ss = st.streams.get(stream)
        if ss is None:
            ss = st.streams[stream] = StreamState()
        ss.observe(seq, ts)
        if stream == "position" and ss.last_seq == seq:
            st.position = PositionPublic(x=data["x"], y=data["y"], z=data.get("z") or 0.0, yaw=data.get("yaw"), ts=ts)
        if st.stale_reported:
            st.stale_reported = False
            self.push(st)

    def tick(self, now: float) -> None:
        """Periodic: stale transitions, legacy robots gone quiet, lazy persistence of last_seen."""
        for st in self.robots.values():
            if st.legacy and st.online and st.last_seen is not None and now - st.last_seen > self._legacy_offline_after:
                self.set_online(st, False, now, "legacy-silence")
            elif (
                not st.legacy
                and st.online
                and st.keepalive_s is not None
                and st.last_heard is not None
                and now - st.last_heard > LINK_SILENCE_FACTOR * st.keepalive_s
            ):
                log.warning(
                    "robot %s silent for %.1f s (keepalive %g s): shown offline",
                    st.id,
                    now - st.last_heard,
                    st.keepalive_s,
                    extra={"robot_id": st.id},
                )
                self.set_online(st, False, now, "link-silent")
                st.silenced = True
            stale = st.is_stale(now, self._stale_after)
            if stale != st.stale_reported:
                st.stale_reported = stale
                self.push(st)
            if st.dirty and now - st.persisted_at >= PERSIST_EVERY_S:
                self.persist(st)

    # -- side effects ----------------------------------------------------------------------------------
    def persist(self, st: RobotState) -> None:
        """Store what the robot said of itself. Never its legacy registration (``legacy``, the topic it
        listens on): only the registrations write those, and a replica's stale view must not undo them."""
        st.dirty = False
        st.persisted_at = time.time()
        self._writer.submit(
            repo.upsert_robot(
                {
                    "id": st.id,
                    "agent_version": st.agent_version,
                    "capabilities": st.capabilities.model_dump(),
                    "first_seen": st.first_seen,
                    "last_seen": st.last_seen,
                    "online": st.online,
                }
            )
        )

    def push(self, st: RobotState) -> None:
        self._hub.publish_control({"type": "robot", "robot": self.public(st).model_dump(mode="json")}, st.id)

    def event(self, kind: str, robot_id: str | None, detail: dict[str, Any], ts: float | None = None) -> None:
        if kind in ("online", "offline"):
            log.info("robot %s %s (%s)", robot_id, kind, detail.get("source", ""), extra={"robot_id": robot_id})
        self._writer.submit(repo.insert_event(time.time() if ts is None else ts, kind, robot_id, detail))
