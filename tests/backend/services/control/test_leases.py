"""One operator in control, and the audit trail, against a real server (authentication on), broker and agent.
Two replicas sharing one lease: tests/system/test_replicas_ownership.py."""

from __future__ import annotations

import time

from tests.backend.helpers import ProbeRobot, wait_robot
from tests.backend.helpers import audit_trail as _audit
from tests.backend.helpers import operator_token as _operator
from tests.support.dbfault import database_away
from tests.support.procs import ServerProcess, wait_for

DRIVE = {"command": "move_forward", "args": {"speed": 0.3, "duration_s": 0.3}}


def test_two_operators_one_robot_request_grant_takeover_and_audit(server, spawn_agent):
    spawn_agent("lease-1")
    alice, _ = _operator(server, "alice")
    bob, bob_holder = _operator(server, "bob")
    with server.client(alice) as a, server.client(bob) as b, server.client() as admin:
        wait_robot(admin, "lease-1", lambda r: r["online"])
        assert admin.get("/api/robots/lease-1/lease").json() is None

        # alice drives: the lease is hers; bob's drive is refused, naming her and her last command
        assert a.post("/api/robots/lease-1/commands", json=DRIVE).status_code == 202
        robot = admin.get("/api/robots/lease-1").json()
        assert robot["lease"]["holder_name"] == "alice"
        refused = b.post("/api/robots/lease-1/commands", json=DRIVE)
        assert refused.status_code == 409, refused.text
        assert "driven by alice" in refused.json()["detail"] and "s ago" in refused.json()["detail"]
        assert a.post("/api/robots/lease-1/commands", json=DRIVE).status_code == 202  # she still can

        # stop, the e-stop and holds never need the lease
        assert b.post("/api/robots/lease-1/commands", json={"command": "stop"}).status_code == 202
        assert b.post("/api/estop", json={"reason": "test"}).status_code == 202
        assert a.post("/api/estop/release", json={}).status_code == 202

        # bob asks; alice grants; now bob drives and alice is refused
        assert b.post("/api/robots/lease-1/lease/request").status_code == 200
        r = a.post("/api/robots/lease-1/lease/grant", json={"to_holder": bob_holder, "to_name": "bob"})
        assert r.status_code == 200 and r.json()["holder_name"] == "bob", r.text
        assert b.post("/api/robots/lease-1/commands", json=DRIVE).status_code == 202
        assert a.post("/api/robots/lease-1/commands", json=DRIVE).status_code == 409
        # only the holder can grant
        assert a.post("/api/robots/lease-1/lease/grant", json={"to_holder": "token:x"}).status_code == 409

        # an operator cannot take it over; an admin can (audited)
        assert a.post("/api/robots/lease-1/lease?force=true").status_code == 403
        assert a.post("/api/robots/lease-1/lease").status_code == 409
        taken = admin.post("/api/robots/lease-1/lease?force=true")
        assert taken.status_code == 200 and taken.json()["holder_name"] == "FLEET_ADMIN_TOKEN", taken.text
        assert b.post("/api/robots/lease-1/commands", json=DRIVE).status_code == 409
        assert admin.delete("/api/robots/lease-1/lease").status_code == 204
        assert admin.get("/api/robots/lease-1/lease").json() is None

    steps = wait_for(
        lambda: (
            (s := [(e["actor_name"], e["action"]) for e in _audit(server) if e["action"] != "command"])
            and ("FLEET_ADMIN_TOKEN", "lease_release") in s
            and s
        ),
        10,
        what="the audit trail",
    )
    assert steps == [
        ("FLEET_ADMIN_TOKEN", "token_create"),  # alice's and bob's tokens
        ("FLEET_ADMIN_TOKEN", "token_create"),
        ("alice", "lease_take"),
        ("bob", "estop"),
        ("alice", "estop_release"),
        ("bob", "lease_request"),
        ("bob", "lease_take"),
        ("alice", "lease_grant"),
        ("FLEET_ADMIN_TOKEN", "lease_take"),
        ("FLEET_ADMIN_TOKEN", "lease_takeover"),
        ("FLEET_ADMIN_TOKEN", "lease_release"),
    ]
    commands = _audit(server, action="command")
    assert [(e["actor_name"], e["detail"]["command"]) for e in commands] == [
        ("alice", "move_forward"),
        ("alice", "move_forward"),
        ("bob", "stop"),
        ("bob", "move_forward"),
    ]
    assert all(e["token_id"] and e["client"] == "127.0.0.1" for e in commands)
    with server.client(alice) as a:
        assert a.get("/api/audit").status_code == 403  # admins only


def test_logging_out_releases_the_users_leases(server, spawn_agent):
    spawn_agent("lease-2")
    with server.client() as admin:
        r = admin.post("/api/users", json={"username": "carol", "password": "carol-password-1", "role": "operator"})
        assert r.status_code == 201, r.text
        wait_robot(admin, "lease-2", lambda r: r["online"])
    with server.client(anonymous=True) as c:
        assert c.post("/api/auth/login", json={"username": "carol", "password": "carol-password-1"}).status_code == 200
        assert (
            c.post("/api/robots/lease-2/commands", json=DRIVE, headers={"Origin": server.base_url}).status_code == 202
        )
        assert c.get("/api/robots/lease-2/lease").json()["holder_name"] == "carol"
        assert c.post("/api/auth/logout", headers={"Origin": server.base_url}).status_code == 204
    with server.client() as admin:
        assert admin.get("/api/robots/lease-2/lease").json() is None


def test_with_authentication_off_each_client_id_is_its_own_holder(broker, database_url, workdir, spawn_agent):
    s = ServerProcess(broker, database_url, workdir, FLEET_AUTH="off")
    s.start()
    try:
        spawn_agent("lease-3")
        with s.client() as c:
            wait_robot(c, "lease-3", lambda r: r["online"])
            tab1, tab2 = {"X-Fleet-Client": "tab-1"}, {"X-Fleet-Client": "tab-2"}
            assert c.post("/api/robots/lease-3/commands", json=DRIVE, headers=tab1).status_code == 202
            refused = c.post("/api/robots/lease-3/commands", json=DRIVE, headers=tab2)
            assert refused.status_code == 409 and "client:tab-1" in refused.json()["detail"]
    finally:
        s.stop()


def test_a_goal_holds_its_lease_past_the_lapse_until_it_ends(broker, database_url, workdir, spawn_agent):
    """A goto takes longer than the lease's lapse (2 s here) without any drive command: the lease stays its
    sender's while the goal runs (another operator's drive is refused), and lapses once the goal has ended."""
    server = ServerProcess(broker, database_url, workdir, FLEET_LEASE_LAPSE_S="2")
    server.start()
    try:
        spawn_agent("lease-goal", "--start-pose=-1.5,0,0")
        alice, _ = _operator(server, "alice")
        bob, _ = _operator(server, "bob")
        with server.client(alice) as a, server.client(bob) as b, server.client() as admin:
            wait_robot(admin, "lease-goal", lambda r: r["online"])
            # a plain drive's lease lapses after 2 s: bob may drive then (the rule the goal must beat)
            assert a.post("/api/robots/lease-goal/commands", json=DRIVE).status_code == 202
            assert b.post("/api/robots/lease-goal/commands", json=DRIVE).status_code == 409
            wait_for(lambda: b.post("/api/robots/lease-goal/commands", json=DRIVE).status_code == 202, 6, interval=0.5)
            assert b.post("/api/robots/lease-goal/commands", json={"command": "stop"}).status_code == 202
            wait_for(lambda: admin.get("/api/robots/lease-goal/lease").json() is None, 6, what="bob's lease lapsed")

            goal = {"command": "goto", "args": {"x": 1.5, "y": 0.0, "tolerance_m": 0.05}}
            r = a.post("/api/robots/lease-goal/commands", json=goal)
            assert r.status_code == 202, r.text
            cid = r.json()["id"]
            time.sleep(5.0)  # 2.5 lapses without a drive command
            status = admin.get(f"/api/commands/{cid}").json()["status"]
            assert status == "accepted", status  # still under way
            refused = b.post("/api/robots/lease-goal/commands", json=DRIVE)
            assert refused.status_code == 409 and "driven by alice" in refused.json()["detail"], refused.text

            assert a.post("/api/robots/lease-goal/commands", json={"command": "stop"}).status_code == 202
            wait_for(
                lambda: b.post("/api/robots/lease-goal/commands", json=DRIVE).status_code == 202,
                8,
                interval=0.5,
                what="the lease lapsing once the goal ended",
            )
    finally:
        server.stop()


def test_a_lease_asked_while_the_database_is_away_is_refused_at_once(server, spawn_agent, database_url):
    """A lease is of the moment: taken while the database is away it is refused (503 database_unavailable)
    instead of waiting for the database and being written minutes later with a stale time; the drive that
    needed it is not sent. Once the database is back, the same drive takes the lease."""
    spawn_agent("lease-away")
    with server.client() as admin:
        wait_robot(admin, "lease-away", lambda r: r["online"])
        with database_away(database_url):
            refused = admin.post("/api/robots/lease-away/commands", json=DRIVE, timeout=30)
            assert refused.status_code == 503, refused.text
            assert refused.json()["code"] == "database_unavailable"
            assert admin.get("/api/robots/lease-away").json()["lease"] is None
        wait_for(
            lambda: admin.post("/api/robots/lease-away/commands", json=DRIVE).status_code == 202,
            20,
            what="the drive taking the lease once the database is back",
        )
        assert admin.get("/api/robots/lease-away").json()["lease"] is not None


def test_a_grant_names_the_new_holder_as_the_server_knows_them(server, mqtt_probe):
    """Issue 29 #6: the lease and the audit trail name whom the holder granted control to by their credentials,
    never by the name the granting client typed; a grant to no one who may drive is refused."""
    ProbeRobot(mqtt_probe, "lease-g").status()
    alice, _ = _operator(server, "alice")
    bob, bob_holder = _operator(server, "bob")
    with server.client() as admin:
        r = admin.post("/api/tokens", json={"name": "vera", "role": "viewer"})
        viewer_holder = f"token:{r.json()['id']}"
    with server.client(alice) as a, server.client(bob) as b:
        wait_robot(a, "lease-g", lambda r: r["online"])
        assert a.post("/api/robots/lease-g/lease").status_code == 200
        assert b.post("/api/robots/lease-g/lease/request").status_code == 200
        granted = a.post("/api/robots/lease-g/lease/grant", json={"to_holder": bob_holder, "to_name": "carol"})
        assert granted.status_code == 200, granted.text
        assert (granted.json()["holder"], granted.json()["holder_name"]) == (bob_holder, "bob")
        for nobody in ("token:tok_nope", viewer_holder, "user:nobody", "mission:m-1", "bob"):
            r = b.post("/api/robots/lease-g/lease/grant", json={"to_holder": nobody, "to_name": "bob"})
            assert (r.status_code, r.json()["code"]) == (409, "unknown_holder"), (nobody, r.text)
        assert b.get("/api/robots/lease-g/lease").json()["holder"] == bob_holder

    def granted_rows() -> list[dict] | None:
        rows = [e for e in _audit(server) if e["action"] in ("lease_grant", "lease_take")]
        return rows if len(rows) >= 3 else None

    rows = wait_for(granted_rows, 5, what="the grant in the audit trail")
    assert [(e["action"], e["actor"], e["actor_name"], e["detail"]) for e in rows] == [
        ("lease_take", rows[0]["actor"], "alice", {"via": "take"}),
        ("lease_take", bob_holder, "bob", {"via": "grant"}),
        ("lease_grant", rows[0]["actor"], "alice", {"to": "bob", "to_holder": bob_holder}),
    ]
    assert rows[1]["token_id"] == bob_holder.removeprefix("token:")
