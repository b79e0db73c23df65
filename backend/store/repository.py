"""Repository layer: write operations (run by the writer thread) and reads (run in a threadpool)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sqlalchemy import Connection, Engine, insert, select, text, update
from sqlalchemy.dialects import postgresql, sqlite

from backend.models import RESOLUTIONS, CommandAckRow, CommandRow, EventRow, Robot
from backend.schemas import AckPublic, CommandPublic, EventPublic, StreamStats
from fleet_protocol import FINAL_ACK_STATUSES

# ---------------------------------------------------------------------------------------------------
# Writes: each returns an op for BatchWriter.submit (executed inside a transaction on the writer thread)
# ---------------------------------------------------------------------------------------------------


def upsert_robot(values: dict[str, Any]) -> Callable[[Connection], None]:
    def op(conn: Connection) -> None:
        ins = (postgresql.insert(Robot) if conn.dialect.name == "postgresql" else sqlite.insert(Robot)).values(**values)
        changes = {k: ins.excluded[k] for k in values if k not in ("id", "first_seen")}
        conn.execute(ins.on_conflict_do_update(index_elements=["id"], set_=changes))

    return op


def insert_event(ts: float, kind: str, robot_id: str | None, detail: dict[str, Any]) -> Callable[[Connection], None]:
    def op(conn: Connection) -> None:
        conn.execute(insert(EventRow).values(ts=ts, kind=kind, robot_id=robot_id, detail=detail))

    return op


def delete_robot(robot_id: str, telemetry: bool) -> Callable[[Connection], int]:
    """The robot's registry row; with ``telemetry`` also its telemetry rows and aggregates (its commands and
    events stay: they are the history of what was done). Returns the telemetry rows deleted."""

    def op(conn: Connection) -> int:
        conn.execute(text("DELETE FROM robots WHERE id = :r"), {"r": robot_id})
        if not telemetry:
            return 0
        deleted = conn.execute(text("DELETE FROM telemetry WHERE robot_id = :r"), {"r": robot_id}).rowcount
        for table in [f"telemetry_{res}" for res in RESOLUTIONS] + ["telemetry_dirty"]:
            conn.execute(text(f"DELETE FROM {table} WHERE robot_id = :r"), {"r": robot_id})
        return int(deleted or 0)

    return op


def insert_command(values: dict[str, Any]) -> Callable[[Connection], None]:
    def op(conn: Connection) -> None:
        conn.execute(insert(CommandRow).values(**values))

    return op


def update_command(
    command_id: str, status: str, reason: str, updated_at: float, ack: dict[str, Any] | None = None
) -> Callable[[Connection], None]:
    def op(conn: Connection) -> None:
        if ack is not None:
            conn.execute(_insert_ack(conn, command_id, ack))
        conn.execute(
            update(CommandRow)
            .where(CommandRow.id == command_id)
            .values(status=status, reason=reason, updated_at=updated_at)
        )

    return op


def _insert_ack(conn: Connection, command_id: str, ack: dict[str, Any]) -> Any:
    """Each replica records the acks it receives: the same ack (command, status, robot ts) is stored once."""
    ins = postgresql.insert(CommandAckRow) if conn.dialect.name == "postgresql" else sqlite.insert(CommandAckRow)
    return ins.values(command_id=command_id, **ack).on_conflict_do_nothing(
        index_elements=["command_id", "status", "ts"]
    )


def apply_ack_if_known(
    command_id: str, robot_id: str, ack: dict[str, Any]
) -> Callable[[Connection], CommandPublic | None]:
    """An ack for a command this process does not hold in memory (sent before a restart, or through another
    replica); a final status is never downgraded. Returns the command with all its acks (None: unknown)."""

    def op(conn: Connection) -> CommandPublic | None:
        row = conn.execute(
            select(CommandRow.status).where(CommandRow.id == command_id, CommandRow.robot_id == robot_id)
        ).first()
        if row is None:
            return None
        conn.execute(_insert_ack(conn, command_id, ack))
        if row.status not in FINAL_ACK_STATUSES or ack["status"] in FINAL_ACK_STATUSES:
            conn.execute(
                update(CommandRow)
                .where(CommandRow.id == command_id)
                .values(status=ack["status"], reason=ack["reason"], updated_at=ack["received_ts"])
            )
        rows = list(conn.execute(select(CommandRow).where(CommandRow.id == command_id)).all())
        found = _commands_with_acks(conn, rows)
        return found[0] if found else None

    return op


# ---------------------------------------------------------------------------------------------------
# Reads (blocking: call through run_in_threadpool)
# ---------------------------------------------------------------------------------------------------


def ping(engine: Engine) -> bool:
    try:
        with engine.connect() as conn:
            conn.execute(text("SELECT 1"))
        return True
    except Exception:
        return False


def load_robots(engine: Engine) -> list[Robot]:
    with engine.connect() as conn:
        rows = conn.execute(select(Robot)).all()
    return [Robot(**r._asdict()) for r in rows]


def _commands_with_acks(conn: Connection, rows: list[Any]) -> list[CommandPublic]:
    ids = [r.id for r in rows]
    acks: dict[str, list[AckPublic]] = {i: [] for i in ids}
    if ids:
        ack_rows = conn.execute(
            # in the robot's order: received_ts comes from whichever replica stored the ack first, and two
            # replicas' receptions of consecutive acks need not be in order
            select(CommandAckRow).where(CommandAckRow.command_id.in_(ids)).order_by(CommandAckRow.ts, CommandAckRow.id)
        ).all()
        for a in ack_rows:
            acks[a.command_id].append(AckPublic(status=a.status, reason=a.reason, ts=a.ts, received_ts=a.received_ts))
    return [
        CommandPublic(
            id=r.id,
            robot_id=r.robot_id,
            command=r.command,
            args=r.args,
            source=r.source,
            ts=r.ts,
            ttl_s=r.ttl_s,
            status=r.status,
            reason=r.reason,
            acks=acks[r.id],
        )
        for r in rows
    ]


def get_command(engine: Engine, command_id: str) -> CommandPublic | None:
    with engine.connect() as conn:
        rows = list(conn.execute(select(CommandRow).where(CommandRow.id == command_id)).all())
        found = _commands_with_acks(conn, rows)
    return found[0] if found else None


def list_commands(
    engine: Engine, robot_id: str, limit: int, start: float | None, end: float | None
) -> list[CommandPublic]:
    q = select(CommandRow).where(CommandRow.robot_id == robot_id)
    if start is not None:
        q = q.where(CommandRow.ts >= start)
    if end is not None:
        q = q.where(CommandRow.ts <= end)
    q = q.order_by(CommandRow.ts.desc()).limit(limit)
    with engine.connect() as conn:
        rows = list(conn.execute(q).all())
        return _commands_with_acks(conn, rows)


def _robot_streams(conn: Connection, table: str, robot_id: str) -> list[str]:
    """The robot's streams by a loose index scan (one index probe per stream, not a scan of its rows)."""
    out: list[str] = []
    row = conn.execute(
        text(f"SELECT stream FROM {table} WHERE robot_id = :r ORDER BY stream LIMIT 1"), {"r": robot_id}
    ).first()
    while row is not None:
        out.append(row[0])
        row = conn.execute(
            text(f"SELECT stream FROM {table} WHERE robot_id = :r AND stream > :s ORDER BY stream LIMIT 1"),
            {"r": robot_id, "s": row[0]},
        ).first()
    return out


def _stream_stat(conn: Connection, robot_id: str, stream: str) -> StreamStats:
    """Count and first/last time of one stream from the rollups plus the raw rows they do not cover yet
    (dirty minutes), so a stream of millions of rows costs a few index lookups, not a scan."""
    key = {"r": robot_id, "s": stream}
    pair = "robot_id = :r AND stream = :s"
    dirty = [
        float(m) for (m,) in conn.execute(text(f"SELECT minute_ts FROM telemetry_dirty WHERE {pair} ORDER BY 1"), key)
    ]
    # minutes the per-minute table answers for: sealed ones, and rolled-up ones not dirty since
    agg_n = conn.execute(
        text(
            f"SELECT coalesce(sum(n), 0) FROM telemetry_1m m WHERE {pair} AND (sealed OR NOT EXISTS ("
            "SELECT 1 FROM telemetry_dirty d WHERE d.robot_id = m.robot_id AND d.stream = m.stream "
            "AND d.minute_ts = m.bucket_ts))"
        ),
        key,
    ).scalar_one()
    raw_n = 0
    runs: list[list[float]] = []
    for m in dirty:
        if runs and m == runs[-1][1]:
            runs[-1][1] = m + 60.0
        else:
            runs.append([m, m + 60.0])
    for lo, hi in runs:
        raw_n += conn.execute(
            text(f"SELECT count(*) FROM telemetry WHERE {pair} AND ts >= :lo AND ts < :hi"), {**key, "lo": lo, "hi": hi}
        ).scalar_one()
    where = f"FROM telemetry WHERE {pair}"
    lo_raw, hi_raw = conn.execute(text(f"SELECT (SELECT min(ts) {where}), (SELECT max(ts) {where})"), key).one()
    lo_agg, hi_agg = conn.execute(
        text(f"SELECT min(first_ts), max(last_ts) FROM telemetry_1m WHERE {pair} AND sealed"), key
    ).one()
    los = [v for v in (lo_raw, lo_agg) if v is not None]
    his = [v for v in (hi_raw, hi_agg) if v is not None]
    return StreamStats(
        stream=stream,
        count=int(agg_n) + int(raw_n),
        first_ts=min(los) if los else None,
        last_ts=max(his) if his else None,
    )


def stream_stats(engine: Engine, robot_id: str) -> list[StreamStats]:
    with engine.connect() as conn:
        streams = sorted(
            set(_robot_streams(conn, "telemetry", robot_id)) | set(_robot_streams(conn, "telemetry_1m", robot_id))
        )
        return [_stream_stat(conn, robot_id, s) for s in streams]


def list_events(
    engine: Engine, start: float | None, end: float | None, kind: str | None, robot_id: str | None, limit: int
) -> list[EventPublic]:
    q = select(EventRow)
    if start is not None:
        q = q.where(EventRow.ts >= start)
    if end is not None:
        q = q.where(EventRow.ts <= end)
    if kind is not None:
        q = q.where(EventRow.kind == kind)
    if robot_id is not None:
        q = q.where(EventRow.robot_id == robot_id)
    q = q.order_by(EventRow.ts.desc(), EventRow.id.desc()).limit(limit)
    with engine.connect() as conn:
        return [
            EventPublic(ts=r.ts, kind=r.kind, robot_id=r.robot_id, detail=r.detail or {}) for r in conn.execute(q).all()
        ]
