"""GET /api/site (the pool outline from FLEET_POOL_BOUNDARY) and GET /api/units (the one units table)."""

from __future__ import annotations

import json
import time

import orjson
import pytest
from pydantic import ValidationError

from backend.core.config import Settings
from fleet_protocol import AvoidanceSettings
from fleet_protocol.units import STREAM_UNITS, unit_of
from robot_agent.sim.world import PoolBounds
from tests.support.procs import ServerProcess, wait_for


def test_site_defaults_to_the_simulators_pool_and_needs_a_login(server):
    b = PoolBounds()
    with server.client() as c:
        site = c.get("/api/site").json()
        assert site["boundary"] == [[b.xmin, b.ymin], [b.xmax, b.ymin], [b.xmax, b.ymax], [b.xmin, b.ymax]]
        assert site["frame"] == "lighthouse" and site["units"] == "m" and site["source"] == "setting"
        assert site["version"] >= 1 and site["configured"] is True and site["keepouts"] == []
        units = c.get("/api/units").json()
        assert units["streams"] == STREAM_UNITS and units["time"].startswith("s ")
    with server.client(anonymous=True) as anon:
        assert anon.get("/api/site").status_code == 401
        assert anon.get("/api/units").status_code == 401


def test_site_follows_the_setting(broker, database_url, workdir):
    boundary = [[0.0, 0.0], [6.0, 0.0], [6.0, 3.0], [1.5, 4.0], [0.0, 3.0]]
    server = ServerProcess(broker, database_url, workdir, FLEET_POOL_BOUNDARY=json.dumps(boundary))
    server.start()
    try:
        with server.client() as c:
            site = c.get("/api/site").json()
        assert site["boundary"] == boundary
    finally:
        server.stop()


@pytest.mark.parametrize(
    "value",
    ["[[0,0],[1,1]]", '[[0,0],[1,0],["a",1]]', "[[0,0],[1,0],[1,1e999]]", "[[0,0,0],[1,0,0],[1,1,0]]", "not json"],
)
def test_a_bad_boundary_is_refused_with_a_clear_error(monkeypatch, value):
    monkeypatch.setenv("FLEET_POOL_BOUNDARY", value)
    with pytest.raises((ValidationError, ValueError)) as err:
        Settings()
    assert "pool_boundary" in str(err.value)


def test_units_lookup():
    assert unit_of("position", "x") == "m" and unit_of("position", "x_max") == "m"
    assert unit_of("position", "count") == ""
    assert unit_of("imu", "accel[2]") == "m/s²" and unit_of("imu", "gyro[0]") == "rad/s"
    assert unit_of("apriltag", "tag3.translation_mm[2]") == "mm"
    assert unit_of("apriltag", "tag3.euler_deg.yaw") == "deg"
    assert unit_of("position", "nope") is None and unit_of("battery", "volts") is None


# -- the site as admins change it: versions, validation, audit, and what the robots receive ----------------

SQUARE = [[-1.5, -1.5], [1.5, -1.5], [1.5, 1.5], [-1.5, 1.5]]
KEEPOUT = [[0.2, 0.2], [0.6, 0.2], [0.6, 0.6], [0.2, 0.6]]
TAG = {"id": 3, "size_m": 0.1, "pose": {"x": 1.5, "y": 0.0, "z": -0.2, "yaw": 3.14}}
GOOD = {"boundary": SQUARE, "keepouts": [KEEPOUT], "tags": [TAG]}
DEFAULTS = AvoidanceSettings().model_dump()


def _retained_site(probe) -> dict:
    """The retained ``fleet/site`` message as a robot that subscribes now receives it."""
    probe.subscribe("fleet/site")
    return probe.wait(lambda m: m.topic == "fleet/site" and m.retain, 10).json()


def test_an_admin_sets_the_site_and_each_version_is_kept_audited_and_published(server, mqtt_probe, role_client):
    with server.client() as c:
        first = c.get("/api/site").json()
        assert first["source"] == "setting" and first["updated_by"] == "FLEET_POOL_BOUNDARY"
        retained = _retained_site(mqtt_probe())
        assert retained["version"] == first["version"] and retained["site"]["boundary"] == first["boundary"]

        r = c.put("/api/site", json=GOOD)
        assert r.status_code == 200, r.text
        new = r.json()
        assert new["version"] == first["version"] + 1 and new["source"] == "api" and new["updated_by"]
        assert new["boundary"] == SQUARE and new["keepouts"] == [KEEPOUT] and new["tags"] == [TAG]
        assert c.get("/api/site").json() == new
        versions = c.get("/api/site/versions").json()
        assert [v["version"] for v in versions] == [new["version"], first["version"]]
        assert versions[1]["boundary"] == first["boundary"]  # the old version is kept as it was

        retained = _retained_site(mqtt_probe())  # a robot subscribing now gets the new version
        assert retained["version"] == new["version"]
        assert retained["site"]["boundary"] == SQUARE and retained["site"]["keepouts"] == [KEEPOUT]

        audit = wait_for(lambda: c.get("/api/audit", params={"action": "site"}).json(), 10, what="the audit row")
        assert audit[0]["detail"]["version"] == new["version"] and audit[0]["detail"]["configured"] is True

    operator = role_client("operator")
    assert operator.get("/api/site").status_code == 200
    r = operator.put("/api/site", json=GOOD)
    assert r.status_code == 403 and r.json()["code"] == "forbidden"
    assert operator.delete("/api/site").status_code == 403


def test_no_site_is_a_published_state_of_its_own(server, mqtt_probe):
    with server.client() as c:
        before = c.get("/api/site").json()
        r = c.delete("/api/site")
        assert r.status_code == 200, r.text
        gone = r.json()
        assert gone["configured"] is False and gone["boundary"] == [] and gone["version"] == before["version"] + 1
        retained = _retained_site(mqtt_probe())
        # no fence, but the robots keep apart: the safety filter's settings go with "no site" too
        assert retained == {"version": gone["version"], "site": None, "ts": retained["ts"], "avoidance": DEFAULTS}
        again = c.put("/api/site", json={"boundary": SQUARE}).json()
        assert again["configured"] is True and again["version"] == gone["version"] + 1


BOWTIE = [[0, 0], [1, 1], [1, 0], [0, 1]]
STATION = {"id": 1, "position": [0, 0, 2], "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}
STATION_ID_20_DIGITS = b'{"id": -27127826520577748992, "position": [0, 0, 2], "rotation": [[1,0,0],[0,1,0],[0,0,1]]}'
BAD_SITES = [
    ("NaN", b'{"boundary": [[NaN, 0], [1, 0], [1, 1]]}', "validation_error"),
    ("Infinity", b'{"boundary": [[0, 0], [1e400, 0], [1, 1]]}', "validation_error"),
    ("huge", b'{"boundary": [[0, 0], [1e9, 0], [1, 1]]}', "validation_error"),
    ("boolean", b'{"boundary": [[0, 0], [true, 0], [1, 1]]}', "validation_error"),
    ("empty", b'{"boundary": []}', "validation_error"),
    ("two points", b'{"boundary": [[0, 0], [1, 1]]}', "validation_error"),
    ("self-intersecting", orjson.dumps({"boundary": BOWTIE}), "bad_polygon"),
    ("no area", orjson.dumps({"boundary": [[0, 0], [1, 1], [2, 2]]}), "bad_polygon"),
    ("bad keep-out", orjson.dumps({"boundary": SQUARE, "keepouts": [BOWTIE]}), "bad_polygon"),
    (
        "keep-out outside",
        orjson.dumps({"boundary": SQUARE, "keepouts": [[[1, 1], [3, 1], [3, 3], [1, 3]]]}),
        "keepout_outside_boundary",
    ),
    ("duplicate tag", orjson.dumps({"boundary": SQUARE, "tags": [TAG, {**TAG, "size_m": 0.2}]}), "duplicate_tag"),
    ("unknown tag id", orjson.dumps({"boundary": SQUARE, "tags": [{**TAG, "id": 9999}]}), "validation_error"),
    ("201 corners", orjson.dumps({"boundary": [[i / 1000, (i % 2) / 10] for i in range(201)]}), "validation_error"),
    ("unknown field", orjson.dumps({"boundary": SQUARE, "keep_out": []}), "validation_error"),
    ("avoidance margin", orjson.dumps({"boundary": SQUARE, "avoidance": {"margin_m": 2.5}}), "validation_error"),
    ("avoidance creep", orjson.dumps({"boundary": SQUARE, "avoidance": {"creep_mps": -0.1}}), "validation_error"),
    ("avoidance on", orjson.dumps({"boundary": SQUARE, "avoidance": {"enabled": "yes"}}), "validation_error"),
    ("avoidance key", orjson.dumps({"boundary": SQUARE, "avoidance": {"margin": 0.1}}), "validation_error"),
    # found by schemathesis: a 20-digit station number got a 500 from the store
    (
        "station number",
        b'{"boundary": [[0,0],[1,0],[1,1]], "base_stations": [' + STATION_ID_20_DIGITS + b"]}",
        "validation_error",
    ),
    (
        "not a rotation",
        orjson.dumps(
            {"boundary": SQUARE, "base_stations": [{**STATION, "rotation": [[1.4e287, 0, 0], [0, 1, 0], [0, 0, 1]]}]}
        ),
        "validation_error",
    ),
]


def test_bad_sites_get_a_422_with_a_code_and_change_nothing(server, mqtt_probe):
    with server.client() as c:
        before = c.get("/api/site").json()
        # the "changes nothing" checks below could fail: a good PUT does change the version and the topic
        assert c.put("/api/site", json=GOOD).status_code == 200
        before = c.get("/api/site").json()
        probe = mqtt_probe()
        assert _retained_site(probe)["version"] == before["version"]
        for name, body, code in BAD_SITES:
            r = c.put("/api/site", content=body, headers={"content-type": "application/json"})
            assert r.status_code == 422, (name, r.text)
            assert r.json()["code"] == code, (name, r.text)
            assert r.json()["detail"], name
        assert c.get("/api/site").json() == before
        assert len(c.get("/api/site/versions").json()) == 2
        time.sleep(0.5)  # a publish of a refused site would have arrived by now
        assert [m.json()["version"] for m in probe.matching(lambda m: m.topic == "fleet/site")] == [before["version"]]
        audit = c.get("/api/audit", params={"action": "site"}).json()
        assert len(audit) == 1


def test_the_avoidance_settings_are_versioned_with_the_site_and_published_to_the_robots(
    server, mqtt_probe, role_client
):
    with server.client() as c:
        seeded = c.get("/api/site").json()
        assert seeded["source"] == "setting" and seeded["avoidance"] == DEFAULTS
        assert _retained_site(mqtt_probe())["avoidance"] == DEFAULTS  # the FLEET_POOL_BOUNDARY site has them

        mine = {"enabled": False, "margin_m": 0.12, "creep_mps": 0.05}
        r = c.put("/api/site", json={**GOOD, "avoidance": mine})
        assert r.status_code == 200, r.text
        assert r.json()["avoidance"] == mine and c.get("/api/site").json()["avoidance"] == mine
        retained = _retained_site(mqtt_probe())
        assert retained["version"] == r.json()["version"] and retained["avoidance"] == mine
        # an edit that does not name them (the boundary editor) keeps them; "no site" keeps them
        kept = c.put("/api/site", json={"boundary": SQUARE}).json()
        assert kept["avoidance"] == mine
        gone = c.delete("/api/site").json()
        assert gone["avoidance"] == mine and _retained_site(mqtt_probe())["avoidance"] == mine
        # each version keeps its own
        versions = c.get("/api/site/versions").json()
        assert [v["avoidance"] for v in versions] == [mine, mine, mine, DEFAULTS]
        partial = c.put("/api/site", json={"boundary": SQUARE, "avoidance": {"margin_m": 0.2}}).json()
        assert partial["avoidance"] == {**DEFAULTS, "margin_m": 0.2}
        audit = wait_for(lambda: len(a := c.get("/api/audit", params={"action": "site"}).json()) == 4 and a, 10)
        assert audit[0]["detail"]["avoidance"] == partial["avoidance"]
    r = role_client("operator").put("/api/site", json={"boundary": SQUARE, "avoidance": mine})
    assert r.status_code == 403  # admins only, as the rest of the site
