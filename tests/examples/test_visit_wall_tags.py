"""examples/visit_wall_tags.py with two simulated robots (disturbances on): every wall tag of the site is
visited, and where each robot stood is checked against the positions the server stored."""

from __future__ import annotations

import math
import statistics
import time

from examples.visit_wall_tags import viewpoints, visit_all
from fleet_protocol import Site, SiteTag, default_pool_site
from tests.support.client_motion import publish_site

STANDOFF = 0.6


def _site_with_tags() -> Site:
    """The simulator's pool and its four wall tags (robot_agent/sim/world.py default_tags)."""
    tags = [
        SiteTag(id=0, size_m=0.1, pose={"x": 2.0, "y": 0.0, "z": 0.1, "yaw": math.pi}),
        SiteTag(id=1, size_m=0.1, pose={"x": 0.0, "y": 2.0, "z": 0.1, "yaw": -math.pi / 2}),
        SiteTag(id=2, size_m=0.1, pose={"x": -2.0, "y": 0.0, "z": 0.1, "yaw": 0.0}),
        SiteTag(id=3, size_m=0.1, pose={"x": 0.0, "y": -2.0, "z": 0.1, "yaw": math.pi / 2}),
    ]
    return default_pool_site().model_copy(update={"tags": tags})


def test_every_wall_tag_is_visited(sim_robots, mqtt_probe, fleet):
    site = _site_with_tags()
    publish_site(mqtt_probe(), site, version=2)
    sim_robots(("tv1", 0.4, 0.4, 0.0), ("tv2", -0.4, -0.4, math.pi))
    t0 = time.time()
    visits = visit_all(fleet, ["tv1", "tv2"], site.model_dump(), standoff_m=STANDOFF, max_speed=0.2)
    assert sorted(v.viewpoint.tag_id for v in visits) == [0, 1, 2, 3], visits
    assert {v.robot_id for v in visits} == {"tv1", "tv2"}, "the tags were shared out"
    assert all(v.status == "done" for v in visits), [
        (v.robot_id, v.viewpoint.tag_id, v.status, v.reason) for v in visits
    ]
    time.sleep(1.0)  # the last fixes committed

    for v in visits:
        cmd = fleet.command(v.command_id)
        done_at = next(a["ts"] for a in cmd["acks"] if a["status"] == "done")
        assert done_at > t0
        rows = list(fleet.history_rows(v.robot_id, "position", start=done_at - 0.15, end=done_at + 0.15))
        assert rows, f"no stored fix around {v.robot_id}'s arrival at tag {v.viewpoint.tag_id}"
        x = statistics.fmean(r["data"]["x"] for r in rows)
        y = statistics.fmean(r["data"]["y"] for r in rows)
        err = math.dist((x, y), (v.viewpoint.x, v.viewpoint.y))
        tag = next(t for t in site.tags if t.id == v.viewpoint.tag_id)
        away = math.dist((x, y), (tag.pose["x"], tag.pose["y"]))
        print(f"{v.robot_id} at tag {tag.id}: {err * 100:.1f} cm from its viewpoint, {away:.2f} m from the tag")
        assert err <= 0.06, f"{v.robot_id} stopped {err:.3f} m from the viewpoint of tag {tag.id}"
        assert abs(away - STANDOFF) <= 0.06


def test_a_site_without_tags_is_refused_before_anything_moves(sim_robots, pool_site, fleet):
    from fleet_client import FleetError

    sim_robots(("tv3", 0.0, 0.0, 0.0))
    before = fleet.commands("tv3")
    try:
        visit_all(fleet, ["tv3"], {"boundary": pool_site.boundary, "tags": []})
    except FleetError as exc:
        assert "no wall tags" in str(exc)
    else:
        raise AssertionError("a site without tags was accepted")
    assert fleet.commands("tv3") == before
    assert viewpoints(_site_with_tags().model_dump(), STANDOFF)[0].x == 2.0 - STANDOFF
