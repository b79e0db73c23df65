"""Readers never starve the writer or the control plane: exports opened and left unread (a raw socket
that sends the request and reads nothing, as a laptop on weak pool Wi-Fi does) hold no database
connection; the control plane and live ingest go on beside them; exports over the caps are refused with
429/503 and Retry-After; a download that stops reading is cut off and frees its slot; bad limits get 422."""

from __future__ import annotations

import time
from typing import Any

from bench.rawhttp import read_to_end, response_status
from tests.backend.helpers import ProbeRobot, audit_trail, publish_burst, wait_robot
from tests.support.exports import BIG_ROWS, EXPORT, big_robot, exports, started, unread
from tests.support.procs import wait_for

NEVER_CUT = {"FLEET_EXPORT_STALL_TIMEOUT_S": "3600"}


def test_unread_exports_leave_health_control_and_live_ingest_alone(broker, database_url, workdir, mqtt_probe):
    # more unread exports than the main pool has connections (8 + 8): before, they took them all
    n = 20
    # (no cut-off while the test runs, however slow the machine: the exports stay open and unread)
    env = {"FLEET_EXPORT_MAX_CONCURRENT": str(n), "FLEET_EXPORT_MAX_PER_CLIENT": str(n), **NEVER_CUT}
    with started(broker, database_url, workdir, **env) as server:
        big_robot(server, mqtt_probe, database_url)
        live = ProbeRobot(mqtt_probe, "live")
        live.status()
        socks = [unread(server) for _ in range(n)]
        try:
            assert [response_status(s, timeout=60)[0] for s in socks] == [200] * n
            with server.client() as c:
                c.timeout = 60.0  # the old failure: a pool checkout that waits 30 s, then gives up
                health = c.get("/api/health").json()
                assert health["status"] == "ok" and health["database"]["ok"] is True, health
                stats = exports(c)
                assert stats["running"] == n and stats["cut_stalled"] == 0, stats  # all still open, unread
                wait_robot(c, "live", lambda r: r["online"])
                # the control plane writes through the writer: a lease taken and given back, audited
                assert c.post("/api/robots/live/lease").status_code == 200
                assert c.delete("/api/robots/live/lease").status_code == 204
                assert c.post("/api/estop", json={"reason": "export test"}).status_code == 202
                assert c.post("/api/estop/release").status_code == 202
                wait_for(
                    lambda: {"lease_take", "lease_release"} <= {e["action"] for e in audit_trail(server)},
                    30,
                    what="the lease in the audit trail",
                )
                wait_for(lambda: c.get("/api/events", params={"kind": "estop"}).json(), 30, what="the e-stop event")
                # live QoS 1 telemetry: every message stored (the broker's acks follow the commits)
                t0 = time.time()
                publish_burst(live, "position", [(i, t0 + i * 0.01, {"x": float(i), "y": 0.0}) for i in range(300)])
                page = lambda: c.get("/api/robots/live/telemetry", params={"raw": "true", "limit": 1000}).json()  # noqa: E731
                wait_for(lambda: len(page()["points"]) == 300, 30, what="300 live rows stored")
                assert exports(c)["running"] == n  # the exports were open and unread throughout
        finally:
            for s in socks:
                s.close()


def test_exports_over_the_caps_are_refused_with_retry_after(broker, database_url, workdir, mqtt_probe):
    env = {
        "FLEET_EXPORT_MAX_PER_CLIENT": "2",
        "FLEET_EXPORT_MAX_CONCURRENT": "3",
        "FLEET_EXPORT_RETRY_AFTER_S": "7",
        "FLEET_HISTORY_EXPORT_MAX_ROWS": "50000",
        **NEVER_CUT,
    }
    with started(broker, database_url, workdir, **env) as server:
        big_robot(server, mqtt_probe, database_url)
        with server.client() as c:
            viewer = c.post("/api/tokens", json={"name": "second client", "role": "viewer"}).json()["token"]
            # bounds first: they cost nothing and are refused whatever runs
            for limit in (50001, 10**30):
                r = c.get(f"{EXPORT}&limit={limit}")
                assert r.status_code == 422 and "at most 50000 rows" in r.json()["detail"], r.text[:300]
            run = c.post("/api/runs", json={"name": "capped", "robots": ["big"]}).json()

            mine = [unread(server), unread(server)]
            theirs: list[Any] = []
            try:
                assert [response_status(s)[0] for s in mine] == [200, 200]
                r = c.get(EXPORT)
                assert r.status_code == 429 and r.headers["retry-after"] == "7", r.text[:300]
                assert r.json()["code"] == "too_many_exports" and "FLEET_EXPORT_MAX_PER_CLIENT=2" in r.json()["detail"]
                theirs.append(unread(server, viewer))
                assert response_status(theirs[0])[0] == 200
                for path in (EXPORT, f"/api/runs/{run['id']}/export?format=parquet"):
                    with server.client(viewer) as v:
                        r = v.get(path)
                    assert r.status_code == 503 and r.headers["retry-after"] == "7", r.text[:300]
                    assert r.json()["code"] == "exports_busy"
                assert exports(c)["running"] == 3 and exports(c)["refused_busy"] == 2
            finally:
                for s in mine + theirs:
                    s.close()
            # a client that goes away gives its places back at once
            wait_for(lambda: exports(c)["running"] == 0, 30, what="the closed exports' slots back")
            r = c.get(EXPORT)
            assert r.status_code == 200 and r.text.count("\n") == BIG_ROWS + 1  # the header, the rows
            assert exports(c)["cut_stalled"] == 0


def test_a_download_that_stops_reading_is_cut_off_and_frees_its_slot(broker, database_url, workdir, mqtt_probe):
    env = {"FLEET_EXPORT_MAX_PER_CLIENT": "1", "FLEET_EXPORT_STALL_TIMEOUT_S": "1"}
    with started(broker, database_url, workdir, **env) as server:
        big_robot(server, mqtt_probe, database_url)
        sock = unread(server)
        try:
            assert response_status(sock)[0] == 200
            with server.client() as c:
                wait_for(lambda: exports(c)["cut_stalled"] == 1, 30, what="the unread download cut off")
                assert exports(c)["running"] == 0
                r = c.get(EXPORT)  # the same client again: its slot is free
                assert r.status_code == 200 and r.text.count("\n") == BIG_ROWS + 1
            # the cut download ends without the chunked body's last chunk: the client sees it incomplete
            rest = read_to_end(sock)
            assert 0 < len(rest) < len(r.content) and not rest.endswith(b"0\r\n\r\n")
        finally:
            sock.close()
