"""Data care for the lab admin: ``fleet-server backup``, ``restore`` and ``export``.

SQLite backups use SQLite's online backup API, so they are consistent while the server keeps writing
(WAL). PostgreSQL backups are ``pg_dump`` custom-format archives (``pg_restore`` restores them). An export
is one zip of a time range of a whole run: telemetry as CSV, commands with their acks, events and robots
as JSON, and a manifest - readable without this software.
"""

from __future__ import annotations

import csv
import io
import json
import shutil
import sqlite3
import subprocess
import time
import zipfile
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, make_url, select

from backend.core.config import Settings


class OpsError(RuntimeError):
    """A data-care step that cannot be done; the CLI prints it and exits 1."""


def _sqlite_path(settings: Settings) -> Path | None:
    url = make_url(settings.database_url)
    if url.get_backend_name() != "sqlite":
        return None
    if not url.database or url.database == ":memory:":
        raise OpsError("an in-memory database cannot be backed up")
    return Path(url.database).expanduser()


def _pg_dsn(settings: Settings) -> str:
    url = make_url(settings.database_url).set(drivername="postgresql")
    return url.render_as_string(hide_password=False)


def _check_integrity(path: Path) -> None:
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        result = con.execute("PRAGMA integrity_check").fetchone()[0]
    except sqlite3.DatabaseError as exc:
        raise OpsError(f"{path} is not a usable SQLite database: {exc}") from None
    finally:
        con.close()
    if result != "ok":
        raise OpsError(f"{path}: integrity check failed: {result}")


def backup(settings: Settings, dest: Path) -> str:
    """Write a consistent copy of the database to ``dest``; returns a one-line summary."""
    dest = dest.expanduser()
    if dest.exists():
        raise OpsError(f"{dest} exists; refusing to overwrite a backup")
    dest.parent.mkdir(parents=True, exist_ok=True)
    src = _sqlite_path(settings)
    if src is None:
        if shutil.which("pg_dump") is None:
            raise OpsError("PostgreSQL backup needs pg_dump (apt install postgresql-client); see docs/base-station.md")
        subprocess.run(["pg_dump", "--format=custom", f"--file={dest}", _pg_dsn(settings)], check=True)
        return f"pg_dump archive written to {dest} (restore with pg_restore --clean -d DATABASE {dest})"
    if not src.exists():
        raise OpsError(f"database {src} does not exist")
    source = sqlite3.connect(str(src), timeout=30)
    target = sqlite3.connect(str(dest))
    try:
        source.backup(target, pages=4096, sleep=0.005)  # small steps: the server keeps writing meanwhile
    finally:
        target.close()
        source.close()
    _check_integrity(dest)
    return f"backup of {src} written to {dest} ({dest.stat().st_size} bytes, integrity ok)"


def restore(settings: Settings, archive: Path, force: bool = False) -> str:
    """Replace the database with a backup. Stop the server first; migrations then bring it to head."""
    archive = archive.expanduser()
    if not archive.exists():
        raise OpsError(f"{archive} does not exist")
    dest = _sqlite_path(settings)
    if dest is None:
        if shutil.which("pg_restore") is None:
            raise OpsError("PostgreSQL restore needs pg_restore (apt install postgresql-client)")
        subprocess.run(["pg_restore", "--clean", "--if-exists", "-d", _pg_dsn(settings), str(archive)], check=True)
        return f"restored {archive} into PostgreSQL"
    _check_integrity(archive)
    if dest.exists() and not force:
        raise OpsError(f"{dest} exists; pass --force to replace it (stop the server first)")
    dest.parent.mkdir(parents=True, exist_ok=True)
    source = sqlite3.connect(f"file:{archive}?mode=ro", uri=True)
    target = sqlite3.connect(str(dest), timeout=30)
    try:
        source.backup(target)
    finally:
        target.close()
        source.close()
    from backend.store.db import create_db_engine, current_revision, upgrade_to_head

    engine = create_db_engine(settings)
    try:
        upgrade_to_head(engine)
        revision = current_revision(engine)
    finally:
        engine.dispose()
    return f"restored {archive} into {dest} (schema {revision})"


def _rows(engine: Engine, stmt: Any) -> list[dict[str, Any]]:
    with engine.connect() as conn:
        return [dict(r._mapping) for r in conn.execute(stmt)]


def export_run(settings: Settings, dest: Path, start: float, end: float) -> str:
    """Zip of everything recorded in [start, end]: telemetry.csv, commands.json, events.json, robots.json."""
    from backend.models import CommandAckRow, CommandRow, EventRow, Robot, TelemetryRow
    from backend.store.db import create_db_engine

    if end < start:
        raise OpsError("--end is before --start")
    dest = dest.expanduser()
    engine = create_db_engine(settings)
    try:
        t = TelemetryRow.__table__
        buf = io.StringIO()
        writer = csv.writer(buf)
        writer.writerow(["robot_id", "stream", "ts", "seq", "data", "recv_ts"])
        telemetry_rows = 0
        with engine.connect() as conn:
            result = conn.execution_options(stream_results=True).execute(
                select(t.c.robot_id, t.c.stream, t.c.ts, t.c.seq, t.c.payload, t.c.recv_ts)
                .where(t.c.ts >= start, t.c.ts <= end)
                .order_by(t.c.ts, t.c.robot_id, t.c.stream, t.c.seq)
            )
            for robot_id, stream, ts, seq, payload, recv_ts in result:
                writer.writerow([robot_id, stream, repr(ts), seq, payload, "" if recv_ts is None else repr(recv_ts)])
                telemetry_rows += 1
        c, a, e = CommandRow.__table__, CommandAckRow.__table__, EventRow.__table__
        commands = _rows(engine, select(c).where(c.c.ts >= start, c.c.ts <= end).order_by(c.c.ts))
        ids = [cmd["id"] for cmd in commands]
        acks: dict[str, list[dict[str, Any]]] = {}
        for i in range(0, len(ids), 500):
            for ack in _rows(engine, select(a).where(a.c.command_id.in_(ids[i : i + 500])).order_by(a.c.id)):
                acks.setdefault(ack["command_id"], []).append(ack)
        for cmd in commands:
            cmd["acks"] = acks.get(cmd["id"], [])
        events = _rows(engine, select(e).where(e.c.ts >= start, e.c.ts <= end).order_by(e.c.ts))
        robots = _rows(engine, select(Robot.__table__))
    finally:
        engine.dispose()
    manifest = {
        "format": "mollusca-fleet-export/1",
        "created": time.time(),
        "start": start,
        "end": end,
        "counts": {
            "telemetry": telemetry_rows,
            "commands": len(commands),
            "events": len(events),
            "robots": len(robots),
        },
        "files": {
            "telemetry.csv": "robot_id,stream,ts,seq,data,recv_ts (data = the message's JSON data object; ts = the "
            "robot's clock, recv_ts = when the server received it, its clock; empty: not recorded)",
            "commands.json": "commands sent in the range, each with its acks",
            "events.json": "online/offline, e-stop, rejects",
            "robots.json": "every known robot",
        },
    }
    dest.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(dest, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("manifest.json", json.dumps(manifest, indent=2))
        z.writestr("telemetry.csv", buf.getvalue())
        z.writestr("commands.json", json.dumps(commands, indent=1, default=str))
        z.writestr("events.json", json.dumps(events, indent=1, default=str))
        z.writestr("robots.json", json.dumps(robots, indent=1, default=str))
    return f"exported {manifest['counts']} to {dest}"
