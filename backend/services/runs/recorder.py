"""Experiment runs: start and stop them, annotate them with markers, keep their camera frames.

A run is an index over what the server stores anyway (its robots and its start/end over the telemetry,
commands, events and alarms), plus what is only kept for runs: markers, and camera frames at the run's
rate in the frame store (frames.py). Open runs live in memory too, so that a camera frame
is matched to its runs without a database read; they are loaded back at start, so a run survives a
crash of the server and can be stopped afterwards.
"""

from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import Engine

from backend.core.errors import ServiceError
from backend.schemas import MarkerCreate, MarkerPublic, RunCreate, RunPublic, RunUpdate
from backend.services.access.audit import Actor, AuditService
from backend.services.fleet.registry import Registry, RobotState
from backend.services.live.camera import Frame
from backend.services.live.hub import LiveHub
from backend.services.runs.frames import FrameStore, safe_name
from backend.services.safety.alarms import AlarmService
from backend.store import repository as repo
from backend.store import runs as store
from backend.store.writer import BatchWriter
from fleet_protocol import AgentConfig, redact

log = logging.getLogger(__name__)

#: a marker may be set this far past "now" of a running run (clocks of browser and server differ a little)
MARKER_FUTURE_SLACK_S = 2.0
#: configuration changes kept per robot and run (an agent restarted with other settings during the run)
MAX_CONFIG_CHANGES = 20


def config_record(config: dict[str, Any]) -> dict[str, Any]:
    """What a run keeps of an agent's published configuration (fleet_protocol.AgentConfig)."""
    return {
        "config": redact(config.get("config") or {}),
        "config_ts": config.get("ts"),
        "boot": config.get("boot", ""),
        "config_agent_version": config.get("agent_version", ""),
    }


def agent_info(st: RobotState) -> dict[str, Any]:
    """A robot's agent as a run records it: versions, capabilities and sensors from its status, and the
    effective configuration it published (``config`` null: it published none, e.g. an older agent)."""
    info: dict[str, Any] = {
        "agent_version": st.agent_version,
        "protocol_version": st.protocol_version,
        "legacy": st.legacy,
        "capabilities": st.capabilities.model_dump(mode="json"),
        "sensors": {k: v.model_dump(mode="json") for k, v in st.sensors.items()},
        "config": None,
    }
    if st.config is not None:
        info.update(config_record(st.config))
    return info


def run_public(row: dict[str, Any]) -> RunPublic:
    return RunPublic(
        id=row["id"],
        name=row["name"],
        notes=row["notes"],
        tags=list(row["tags"] or []),
        operator=row["operator"],
        robots=list(row["robots"] or []),
        started_at=row["started_at"],
        ended_at=row["ended_at"],
        running=row["ended_at"] is None,
        site_version=row["site_version"],
        agents=dict(row["agents"] or {}),
        frame_rate=row["frame_rate"],
        frames=row["frames"],
        frame_bytes=row["frame_bytes"],
        frames_stopped=bool(row["frames_stopped"]),
        frames_stopped_reason=row["frames_stopped_reason"],
        mission_id=row.get("mission_id"),
    )


def marker_public(row: dict[str, Any]) -> MarkerPublic:
    return MarkerPublic(**{k: row[k] for k in MarkerPublic.model_fields})


def unknown_run(run_id: int) -> ServiceError:
    return ServiceError(404, f"unknown run {run_id}", "unknown_run")


@dataclass
class OpenRun:
    """What frame recording needs of an open run, in memory."""

    id: int
    robots: frozenset[str]
    started_at: float
    frame_rate: float
    frames_stopped: bool = False
    #: robot -> receive time of the last frame kept
    last_kept: dict[str, float] = field(default_factory=dict)
    frames: int = 0
    #: robot -> agent info as stored with the run (agent_info): a configuration published later updates it
    agents: dict[str, Any] = field(default_factory=dict)


class RunService:
    def __init__(
        self,
        *,
        engine: Engine,
        writer: BatchWriter,
        hub: LiveHub,
        registry: Registry,
        audit: AuditService,
        alarms: AlarmService,
        frames: FrameStore,
    ) -> None:
        self._engine = engine
        self._writer = writer
        self._hub = hub
        self._registry = registry
        self._audit = audit
        self._alarms = alarms
        self.frames = frames
        self.open: dict[int, OpenRun] = {}

    def load(self, rows: list[dict[str, Any]]) -> None:
        """Runs left open (e.g. by a crash) go on recording: they are closed by a stop, as any run."""
        for r in rows:
            self.open[r["id"]] = OpenRun(
                r["id"],
                frozenset(r["robots"]),
                r["started_at"],
                r["frame_rate"],
                bool(r["frames_stopped"]),
                agents=dict(r["agents"] or {}),
            )

    async def _write(self, op: Any) -> Any:
        fut = self._writer.submit(op, want_result=True, after_rows=False)
        if fut is None:
            raise ServiceError(503, "the database write queue is full; try again", "unavailable")
        return await asyncio.wrap_future(fut)

    async def get_row(self, run_id: int) -> dict[str, Any]:
        row = await asyncio.to_thread(store.get_run, self._engine, run_id)
        if row is None:
            raise unknown_run(run_id)
        return row

    # -- start / stop / edit ---------------------------------------------------------------------------------
    async def start(self, actor: Actor, body: RunCreate, site_version: int, mission_id: str | None = None) -> RunPublic:
        """Open a run of ``body.robots`` (every robot online when none); ``mission_id``: the mission opening it."""
        if body.robots is None:
            robots = sorted(st.id for st in self._registry.robots.values() if st.online)
            if not robots:
                raise ServiceError(409, "no robot is online: name the robots to record", "no_robots")
        else:
            robots = sorted(set(body.robots))
            unknown = [r for r in robots if self._registry.get(r) is None]
            if unknown:
                raise ServiceError(404, f"unknown robot(s): {', '.join(map(repr, unknown))}", "unknown_robot")
        agents = {rid: agent_info(self._registry.robots[rid]) for rid in robots}
        tags = list(dict.fromkeys(body.tags))
        now = time.time()
        values = {
            "name": body.name,
            "notes": body.notes,
            "tags": tags,
            "tag_index": store.index_of(tags),
            "operator": actor.name[:160],
            "robots": robots,
            "robot_index": store.index_of(robots),
            "started_at": now,
            "ended_at": None,
            "site_version": site_version,
            "agents": agents,
            "frame_rate": body.frame_rate,
            "frames": 0,
            "frame_bytes": 0,
            "frames_stopped": False,
            "frames_stopped_reason": "",
            "mission_id": mission_id,
        }
        run_id = await self._write(store.insert_run(values))
        # frames left under this id by a database that was reset are not this run's
        await asyncio.to_thread(self.frames.delete, run_id)
        self.open[run_id] = OpenRun(run_id, frozenset(robots), now, body.frame_rate, agents=agents)
        self._writer.submit(repo.insert_event(now, "run_start", None, {"run_id": run_id, "name": body.name}))
        self._audit.record(actor, "run_start", None, {"run_id": run_id, "name": body.name, "robots": robots})
        run = run_public({"id": run_id, **values})
        self._push(run)
        log.info("run %d %r started by %s: %s", run_id, body.name, actor.name, ", ".join(robots))
        return run

    async def stop(self, actor: Actor, run_id: int) -> RunPublic:
        row = await self.get_row(run_id)
        if row["ended_at"] is not None:
            raise ServiceError(409, f"run {run_id} has already ended", "run_ended")
        self.open.pop(run_id, None)
        await asyncio.to_thread(self.frames.flush)
        n, size = await asyncio.to_thread(self.frames.usage, run_id)
        now = time.time()
        changed = await self._write(store.end_run(run_id, now, {"frames": n, "frame_bytes": size}))
        if not changed:  # another stop (or replica) won
            raise ServiceError(409, f"run {run_id} has already ended", "run_ended")
        self._writer.submit(repo.insert_event(now, "run_stop", None, {"run_id": run_id, "name": row["name"]}))
        self._audit.record(actor, "run_stop", None, {"run_id": run_id, "name": row["name"]})
        run = run_public({**row, "ended_at": now, "frames": n, "frame_bytes": size})
        self._push(run)
        return run

    async def update(self, actor: Actor, run_id: int, body: RunUpdate) -> RunPublic:
        """Rename, re-note or re-tag a run (audited: what it was called, and each new value)."""
        row = await self.get_row(run_id)
        values: dict[str, Any] = {}
        if body.name is not None:
            values["name"] = body.name
        if body.notes is not None:
            values["notes"] = body.notes
        if body.tags is not None:
            values["tags"] = list(dict.fromkeys(body.tags))
            values["tag_index"] = store.index_of(values["tags"])
        if values:
            await self._write(store.update_run(run_id, values))
            changed = {k: v for k, v in values.items() if k != "tag_index"}
            self._audit.record(actor, "run_update", None, {"run_id": run_id, "was": row["name"], **changed})
        return run_public({**row, **values})

    async def delete(self, actor: Actor, run_id: int) -> None:
        row = await self.get_row(run_id)
        self.open.pop(run_id, None)
        await self._write(store.delete_run(run_id))
        await asyncio.to_thread(self.frames.flush)
        freed = await asyncio.to_thread(self.frames.delete, run_id)
        self._audit.record(
            actor, "run_delete", None, {"run_id": run_id, "name": row["name"], "frame_bytes_freed": freed}
        )
        self._hub.publish_control({"type": "run_deleted", "id": run_id})

    # -- markers -------------------------------------------------------------------------------------------
    async def add_marker(self, actor: Actor, run_id: int, body: MarkerCreate) -> MarkerPublic:
        row = await self.get_row(run_id)
        now = time.time()
        ts = now if body.ts is None else body.ts
        end = row["ended_at"] if row["ended_at"] is not None else now + MARKER_FUTURE_SLACK_S
        if not row["started_at"] <= ts <= end:
            raise ServiceError(
                409,
                f"marker time {ts:.3f} is outside run {run_id} ({row['started_at']:.3f} .. "
                f"{'now' if row['ended_at'] is None else format(end, '.3f')})",
                "marker_outside_run",
            )
        if body.robot_id is not None and body.robot_id not in row["robots"]:
            raise ServiceError(409, f"robot {body.robot_id!r} is not in run {run_id}", "robot_not_in_run")
        values = {
            "run_id": run_id,
            "ts": ts,
            "text": body.text,
            "robot_id": body.robot_id,
            "author": actor.name[:160],
            "created_at": now,
        }
        marker_id = await self._write(store.insert_marker(values))
        # markers show in the event list as well
        self._writer.submit(
            repo.insert_event(
                ts, "marker", body.robot_id, {"run_id": run_id, "marker_id": marker_id, "text": body.text}
            )
        )
        marker = marker_public({"id": marker_id, **values})
        self._hub.publish_control({"type": "marker", "marker": marker.model_dump(mode="json")})
        return marker

    # -- agents' configurations (event loop) ----------------------------------------------------------------
    def on_agent_config(self, robot_id: str, config: AgentConfig | None, received: float) -> None:
        """A robot published its configuration: the registry keeps it, and every open run of that robot
        records it (the first one, or a change: an agent restarted with other settings during the run)."""
        st = self._registry.apply_config(robot_id, config, received)
        if st is None or st.config is None:
            return
        record = config_record(st.config)
        for run in self.open.values():
            if robot_id not in run.robots:
                continue
            info = dict(run.agents.get(robot_id) or {})
            changes = list(info.get("config_changes") or [])
            latest = changes[-1]["config"] if changes else info.get("config")
            if latest == record["config"]:
                continue
            if info.get("config") is None:  # published after the run started (or the agent came later)
                info.update(record)
            else:  # ``config`` stays what the run started with; later ones are listed in order
                info["config_changes"] = [*changes, {**record, "received": received}][-MAX_CONFIG_CHANGES:]
            run.agents[robot_id] = info
            self._writer.submit(store.update_run(run.id, {"agents": dict(run.agents)}))

    # -- camera frames (event loop) ----------------------------------------------------------------------------
    def on_frame(self, frame: Frame) -> None:
        """Keep the frame for every open run of its robot that is due one (at most the run's rate)."""
        for run in self.open.values():
            if frame.robot_id not in run.robots or run.frames_stopped or run.frame_rate <= 0:
                continue
            if frame.header.ts < run.started_at:  # taken before the run began (it arrived after): not the run's
                continue
            last = run.last_kept.get(frame.robot_id)
            # 5 % slack: a camera at exactly the run's rate keeps every frame despite jitter
            if last is not None and frame.received - last < 0.95 / run.frame_rate:
                continue
            if not safe_name(frame.robot_id):
                continue
            if not self.frames.reserve(len(frame.jpeg)):
                self._quota_reached(run)
                continue
            if self.frames.put(run.id, frame.robot_id, frame.header.ts, frame.header.frame_seq, frame.jpeg):
                run.last_kept[frame.robot_id] = frame.received
                run.frames += 1

    def _quota_reached(self, run: OpenRun) -> None:
        run.frames_stopped = True
        quota_mb = self.frames.quota_bytes / 1e6
        reason = f"the frame store is full ({quota_mb:g} MB quota): camera frames are no longer kept"
        log.warning("run %d: %s", run.id, reason)
        self._writer.submit(store.update_run(run.id, {"frames_stopped": True, "frames_stopped_reason": reason}))
        self._writer.submit(
            repo.insert_event(time.time(), "run_frames_stopped", None, {"run_id": run.id, "reason": reason})
        )
        self._alarms.raise_("", "frames_quota", f"run {run.id}: {reason}", {"run_id": run.id})
        self._hub.publish_control({"type": "run_frames_stopped", "id": run.id, "reason": reason})

    def _push(self, run: RunPublic) -> None:
        self._hub.publish_control({"type": "run", "run": run.model_dump(mode="json")})
