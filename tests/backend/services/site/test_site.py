"""The site service: the geometry an admin may set, the server's geofence on goals, and the whole way from
the server's retained site to a real agent that then accepts a goal and reaches it (real Mosquitto, real
server, real simulated agent with its disturbances on)."""

from __future__ import annotations

import time
from collections.abc import Callable

import orjson
import pytest

from backend.services.site.geofence import ServerFence, SiteRefused, check_site
from fleet_protocol import Site, default_pool_site
from tests.support.motion import DISTURBED
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, Broker, ServerProcess, wait_for

SQUARE = [[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]]
KEEPOUT = [[0.5, -0.5], [1.0, -0.5], [1.0, 0.5], [0.5, 0.5]]


# -- what an admin may set ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("site", "code"),
    [
        ({"boundary": [[0, 0], [1, 1], [1, 0], [0, 1]]}, "bad_polygon"),
        ({"boundary": [[0, 0], [1, 0], [2, 0]]}, "bad_polygon"),
        (
            {"boundary": SQUARE, "keepouts": [[[1.5, 1.5], [2.5, 1.5], [2.5, 2.5], [1.5, 2.5]]]},
            "keepout_outside_boundary",
        ),
        ({"boundary": SQUARE, "keepouts": [[[0, 0], [1, 1], [1, 0], [0, 1]]]}, "bad_polygon"),
        ({"boundary": SQUARE, "tags": [{"id": 1}, {"id": 2}, {"id": 1}]}, "duplicate_tag"),
    ],
)
def test_a_site_that_cannot_be_a_pool_is_refused_with_its_code(site, code):
    with pytest.raises(SiteRefused) as err:
        check_site(site)
    assert err.value.status_code == 422 and err.value.code == code, err.value.detail


def test_a_good_site_passes():
    check_site({"boundary": SQUARE, "keepouts": [KEEPOUT], "tags": [{"id": 1}, {"id": 2}]})


# -- the server's geofence on goals: the robot's rule --------------------------------------------------------


def test_goals_outside_the_boundary_in_a_keepout_or_its_margin_are_refused():
    fence = ServerFence(Site(boundary=SQUARE, keepouts=[KEEPOUT], geofence_margin_m=0.15))
    assert fence.goal_problem("goto", {"x": 0.0, "y": 0.0}) is None
    assert "outside the boundary" in (fence.goal_problem("goto", {"x": 2.5, "y": 0.0}) or "")
    assert "margin of the boundary" in (fence.goal_problem("goto", {"x": 1.9, "y": 0.0}) or "")
    assert "keep-out 0" in (fence.goal_problem("goto", {"x": 0.75, "y": 0.0}) or "")
    assert "keep-out 0" in (fence.goal_problem("goto", {"x": 0.4, "y": 0.0}) or "")  # within its margin
    ok = [[-1.0, -1.0], [-1.0, 1.0], [0.0, 1.2]]
    assert fence.goal_problem("follow_path", {"waypoints": ok, "loop": False}) is None
    # every point inside, but a leg crosses the keep-out
    assert "leg from waypoint 0" in (fence.goal_problem("follow_path", {"waypoints": [[0, 0], [1.5, 0]]}) or "")
    # a loop's closing leg counts
    loop = [[0.0, -1.0], [1.5, -1.0], [1.5, 1.0]]
    assert fence.goal_problem("follow_path", {"waypoints": loop, "loop": False}) is None
    assert "leg from waypoint 2" in (fence.goal_problem("follow_path", {"waypoints": loop, "loop": True}) or "")
    bad_point = [[0.0, 0.0], [3.0, 0.0]]
    assert "waypoint 1" in (fence.goal_problem("follow_path", {"waypoints": bad_point}) or "")


# -- the whole way: server -> retained site -> real agent ---------------------------------------------------

Spawn = Callable[..., AgentProcess]


def _online(c, rid: str) -> None:
    wait_for(lambda: c.get(f"/api/robots/{rid}").json().get("online"), 30, what=f"the server to see {rid}")


def _has_a_fix(probe: MqttProbe, rid: str) -> None:
    """The robot's position stream runs (several fixes in the last half second)."""
    topic = f"fleet/{rid}/telemetry/position"

    def _recent() -> bool:
        return len(probe.matching(lambda m: m.topic == topic and m.at > time.time() - 0.5)) >= 5

    wait_for(_recent, 20, what=f"{rid}'s position fixes")


def _goto(c, rid: str, x: float, y: float, wait: float | None = None):
    params = {"wait": wait} if wait else None
    return c.post(f"/api/robots/{rid}/commands", params=params, json={"command": "goto", "args": {"x": x, "y": y}})


def test_the_servers_site_reaches_a_real_agent_which_then_accepts_and_reaches_a_goal(
    server: ServerProcess, spawn_agent: Spawn, mqtt_probe: Callable[..., MqttProbe]
) -> None:
    probe = mqtt_probe("fleet/s1/cmd", "fleet/s1/ack", "fleet/s1/telemetry/position")
    spawn_agent("s1", *DISTURBED, "--start-pose=-1.2,0,0")
    with server.client() as c:
        _online(c, "s1")
        site = c.get("/api/site").json()
        assert site["boundary"] == SQUARE and site["configured"]
        _has_a_fix(probe, "s1")
        started = time.time()
        # longer than the 10 s every other command may wait: a goal's wait lasts until its final ack
        r = _goto(c, "s1", 0.6, 0.3, wait=60)
        assert r.status_code == 200, r.text
        done = r.json()
        assert done["status"] == "done", done["acks"]
        accepted = [a for a in done["acks"] if a["status"] == "accepted"]
        assert accepted and f"site v{site['version']}" in accepted[0]["reason"], done["acks"]
        topic, now = "fleet/s1/telemetry/position", time.time()
        pos = orjson.loads(probe.wait(lambda m: m.topic == topic and m.at > now, 5).payload)["data"]
        assert abs(pos["x"] - 0.6) < 0.15 and abs(pos["y"] - 0.3) < 0.15, pos
        took = time.time() - started
        print(f"goto done in {took:.1f} s")
        assert took > 10  # 1.8 m at 0.15 m/s: the answer came after the 10 s other commands may wait


def test_a_goal_outside_the_fence_gets_a_422_and_is_never_sent(
    server: ServerProcess, spawn_agent: Spawn, mqtt_probe: Callable[..., MqttProbe]
) -> None:
    probe = mqtt_probe("fleet/s2/cmd")
    spawn_agent("s2", "--start-pose=0,0,0")
    with server.client() as c:
        _online(c, "s2")
        # first: a goal inside is published (so the check below could see one)
        r = _goto(c, "s2", 0.3, 0.0)
        assert r.status_code == 202, r.text
        inside = r.json()["id"]
        probe.wait(lambda m: orjson.loads(m.payload)["id"] == inside, 10)
        refused = [
            ("goto", {"x": 2.5, "y": 0.0}),
            ("goto", {"x": 1.95, "y": 0.0}),
            ("follow_path", {"waypoints": [[0.0, 0.0], [0.5, 0.5], [0.5, 9.0]]}),
        ]
        for command, args in refused:
            r = c.post("/api/robots/s2/commands", json={"command": command, "args": args})
            assert r.status_code == 422 and r.json()["code"] == "geofence", r.text
        # a keep-out added by an admin is honoured at once
        r = c.put("/api/site", json={"boundary": SQUARE, "keepouts": [KEEPOUT]})
        assert r.status_code == 200, r.text
        r = _goto(c, "s2", 0.75, 0.0)
        assert r.status_code == 422 and r.json()["code"] == "geofence" and "keep-out 0" in r.json()["detail"]
        # bad args never go out either
        for command, args in [
            ("goto", {"x": float("nan"), "y": 0.0}),
            ("goto", {"x": 1e9, "y": 0.0}),
            ("follow_path", {"waypoints": [[0.0, 0.0]] * 10_000}),
            ("drive", {"linear": True}),
        ]:
            body = orjson.dumps({"command": command, "args": args}, option=orjson.OPT_SERIALIZE_NUMPY)
            r = c.post("/api/robots/s2/commands", content=body, headers={"content-type": "application/json"})
            assert r.status_code in (413, 422), r.text
            assert r.json()["code"] in ("bad_args", "payload_too_large"), r.text
        time.sleep(1.0)  # a command published by mistake would have arrived by now
        sent = [orjson.loads(m.payload)["id"] for m in probe.matching(lambda m: m.topic == "fleet/s2/cmd")]
        assert sent == [inside]
        # and with no site there is no fence: the same far goal goes out (the robot judges its own limits)
        assert c.delete("/api/site").status_code == 200
        r = _goto(c, "s2", 2.5, 0.0)
        assert r.status_code == 202, r.text


def test_default_pool_site_is_the_servers_default():
    assert default_pool_site().boundary == SQUARE


def test_a_setting_that_is_no_pool_stops_the_first_start_with_its_name():
    from backend.core.config import Settings
    from backend.services.container import _default_site

    assert _default_site(Settings()).boundary == SQUARE
    with pytest.raises(ValueError, match="pool_boundary"):
        _default_site(Settings(pool_boundary=[(0, 0), (1, 1), (1, 0), (0, 1)]))


def test_the_server_puts_its_site_back_on_a_broker_that_forgot_it(
    server: ServerProcess, broker: Broker, mqtt_probe: Callable[..., MqttProbe]
) -> None:
    """A broker restarted without persistence has no retained site: the server publishes the version it holds
    as soon as it is connected again, once (the database holds nothing newer, so no second copy comes before
    the next version)."""
    with server.client() as c:
        version = c.get("/api/site").json()["version"]
    first = mqtt_probe("fleet/site").wait(lambda m: m.topic == "fleet/site", 10)
    assert first.retain and orjson.loads(first.payload)["version"] == version
    broker.kill()
    broker.start()
    probe = mqtt_probe("fleet/site")  # connects to the empty broker: retained or live, the site comes
    again = probe.wait(lambda m: m.topic == "fleet/site", 30)
    assert orjson.loads(again.payload)["version"] == version
    with server.client() as c:  # a new version, published on the same connection after that one
        assert c.put("/api/site", json={"boundary": SQUARE}).status_code == 200
    probe.wait(lambda m: m.topic == "fleet/site" and orjson.loads(m.payload)["version"] == version + 1, 10)
    # the held version came once, before the new one: no second copy of it from the database read
    assert [orjson.loads(m.payload)["version"] for m in probe.matching(lambda m: m.topic == "fleet/site")] == [
        version,
        version + 1,
    ]
