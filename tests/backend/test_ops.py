"""/metrics, JSON logs, backup/restore/export against a running server with a real robot."""

from __future__ import annotations

import csv
import io
import json
import sqlite3
import subprocess
import zipfile
from pathlib import Path

import pytest

from tests.backend.helpers import wait_robot
from tests.support.procs import VENV_BIN, ServerProcess, base_env, wait_for


def _metric(text: str, name: str, **labels: str) -> float:
    """The sample ``name`` with exactly these labels, in whatever order the exposition writes them."""
    want = {f'{k}="{v}"' for k, v in labels.items()}
    for line in text.splitlines():
        key, _, value = line.rpartition(" ")
        sample, _, label_text = key.partition("{")
        if sample == name and set(filter(None, label_text.rstrip("}").split(","))) == want:
            return float(value)
    raise AssertionError(f"{name}{labels} not in /metrics:\n{text[:2000]}")


def test_metrics_count_what_happened(server, spawn_agent, mqtt_probe):
    spawn_agent("m1", "--position-rate", "50")
    with server.client() as c:
        wait_robot(c, "m1", lambda r: r["online"] and r["position"] is not None, timeout=30)
        # a 2 s drive: heard late on a loaded machine it still runs (a drive that ended before it arrived would be
        # acked "expired", rightly); this test is about the metrics
        drive = {"command": "move_forward", "args": {"duration_s": 2.0}, "ttl_s": 10}
        r = c.post("/api/robots/m1/commands?wait=10", json=drive)
        assert r.json()["status"] == "done", r.text
        c.post("/api/robots/m1/commands?wait=3", json={"command": "move_forward", "args": {"speed": 3}})
        mqtt_probe().publish("fleet/m1/telemetry/position", b"{not json")
        wait_for(lambda: "fleet_rejects_total{" in c.get("/metrics").text, 10, what="reject metric")
        # the count grows at 50 Hz; on a loaded machine the first scrape may come before the 11th sample
        wait_for(
            lambda: _metric(c.get("/metrics").text, "fleet_telemetry_messages_total", stream="position") > 10,
            20,
            what="more than ten position samples counted",
        )
        text = c.get("/metrics").text
        assert c.get("/metrics").headers["content-type"].startswith("text/plain")
        assert _metric(text, "fleet_robots_online") == 1
        assert _metric(text, "fleet_telemetry_messages_total", stream="position") > 10
        assert _metric(text, "fleet_command_ack_seconds_count", status="done") == 1
        assert _metric(text, "fleet_command_ack_seconds_count", status="accepted") == 1
        assert _metric(text, "fleet_command_ack_seconds_bucket", status="done", le="+Inf") == 1
        assert _metric(text, "fleet_mqtt_connected") == 1
        # the writer's bookkeeping: what was acked, retried, withheld, given up (issue 28)
        assert _metric(text, "fleet_store_acks_total") > 10  # telemetry is acked after its commit
        for name in (
            "fleet_store_rows_rejected_total",
            "fleet_store_retries_total",
            "fleet_store_failing",
            "fleet_store_ops_retrying",
            "fleet_store_ops_dropped_total",
            "fleet_store_ops_refused_total",
            "fleet_store_acks_withheld_total",
            "fleet_mqtt_acks_withheld",
            "fleet_mqtt_redelivery_reconnects_total",
        ):
            assert _metric(text, name) == 0, name
        assert (
            sum(float(line.split()[-1]) for line in text.splitlines() if line.startswith("fleet_rejects_total{")) >= 1
        )
        # every family declared once with HELP and TYPE
        names = [line.split()[2] for line in text.splitlines() if line.startswith("# TYPE")]
        assert len(names) == len(set(names))


def test_json_logs_carry_robot_id(broker, database_url, workdir, spawn_agent):
    server = ServerProcess(broker, database_url, workdir, FLEET_LOG_FORMAT="json")
    server.start()
    try:
        spawn_agent("j1")
        with server.client() as c:
            wait_robot(c, "j1", lambda r: r["online"], timeout=30)
        entries = wait_for(
            lambda: [e for e in map(_json_or_none, server.output().splitlines()) if e and e.get("robot_id") == "j1"],
            10,
            what="a JSON log line about j1",
        )
        assert {"ts", "level", "logger", "msg"} <= entries[0].keys()
        lines = [ln for ln in server.output().splitlines() if ln.strip()]
        assert all(_json_or_none(ln) is not None for ln in lines), [ln for ln in lines if not _json_or_none(ln)][:3]
    finally:
        server.stop()


def _json_or_none(line: str) -> dict | None:
    try:
        value = json.loads(line)
    except ValueError:
        return None
    return value if isinstance(value, dict) else None


def _cli(*args: str, db: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(VENV_BIN / "fleet-server"), *args],
        env=base_env(FLEET_DATABASE_URL=db),
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_backup_while_running_restore_and_export(server, spawn_agent, workdir: Path, database_url: str):
    if not database_url.startswith("sqlite"):
        pytest.skip("the SQLite online backup path; PostgreSQL uses pg_dump")
    spawn_agent("b1", "--position-rate", "50")
    with server.client() as c:
        wait_robot(c, "b1", lambda r: r["online"] and r["position"] is not None, timeout=30)
        # a command with its acks for the export (its 10 s ttl and 2 s drive: this test is about backups, not
        # latency; a robot just started on a loaded machine can hear it late, and a drive that ended before it
        # arrived is acked "expired", rightly)
        turn = {"command": "turn_left", "args": {"duration_s": 2.0}, "ttl_s": 10}
        done = c.post("/api/robots/b1/commands?wait=10", json=turn)
        assert done.json()["status"] == "done", done.text
        wait_for(
            lambda: len(c.get("/api/robots/b1/telemetry", params={"max_points": 10000}).json()["points"]) > 50,
            10,
            what="stored points",
        )
        backup = workdir / "backups" / "fleet-backup.db"
        r = _cli("backup", str(backup), db=database_url)  # the server keeps writing meanwhile
        assert r.returncode == 0, r.stderr
        assert "integrity ok" in r.stdout
        assert _cli("backup", str(backup), db=database_url).returncode == 1  # never overwrites

        export = workdir / "run.zip"
        r = _cli("export", str(export), "--start", "0", db=database_url)
        assert r.returncode == 0, r.stderr
        stored = c.get("/api/robots/b1/telemetry", params={"max_points": 10000}).json()["points"]

    con = sqlite3.connect(backup)
    backed_up = con.execute("select count(*) from telemetry where robot_id='b1'").fetchone()[0]
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    con.close()
    assert backed_up > 50

    with zipfile.ZipFile(export) as z:
        manifest = json.loads(z.read("manifest.json"))
        rows = list(csv.DictReader(io.StringIO(z.read("telemetry.csv").decode())))
        commands = json.loads(z.read("commands.json"))
        events = json.loads(z.read("events.json"))
    assert manifest["counts"]["telemetry"] == len(rows) > 50
    assert {"robot_id", "stream", "ts", "seq", "data"} <= rows[0].keys()
    b1_pos = [r for r in rows if r["robot_id"] == "b1" and r["stream"] == "position"]
    seqs = [int(r["seq"]) for r in b1_pos]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # every stored point, no gap
    assert json.loads(b1_pos[0]["data"]).keys() >= {"x", "y"}
    # the server's receive time beside the robot's (the agent runs on this machine: the same clock, near)
    assert all(abs(float(r["recv_ts"]) - float(r["ts"])) < 5.0 for r in b1_pos)
    assert commands[0]["command"] == "turn_left" and [a["status"] for a in commands[0]["acks"]] == ["accepted", "done"]
    assert any(e["kind"] == "online" and e["robot_id"] == "b1" for e in events)
    # the export holds every point the API had up to the export's last one (later points arrived after it read)
    last = max(float(r["ts"]) for r in b1_pos)
    assert {p["seq"] for p in stored if p["ts"] <= last} <= set(seqs)

    server.stop()
    target = workdir / "restored.db"
    restored_url = f"sqlite:///{target}"
    r = _cli("restore", str(backup), db=restored_url)
    assert r.returncode == 0, r.stderr
    assert _cli("restore", str(backup), db=restored_url).returncode == 1  # exists: needs --force
    assert _cli("restore", str(backup), "--force", db=restored_url).returncode == 0
    con = sqlite3.connect(target)
    assert con.execute("select count(*) from telemetry where robot_id='b1'").fetchone()[0] == backed_up
    con.close()
    bad = workdir / "not-a-db"
    bad.write_bytes(b"garbage" * 100)
    r = _cli("restore", str(bad), "--force", db=restored_url)
    assert r.returncode == 1 and "not a usable SQLite database" in r.stderr and "Traceback" not in r.stderr
