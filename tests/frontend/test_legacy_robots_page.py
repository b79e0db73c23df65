"""The Users & tokens page's **Robots on the old framework** (issue 29 #2), in a real Chromium against a real
server: an admin registers a robot of the old framework, its anonymous messages are taken from then on and
its row says online; the API's refusal (a robot online with the agent) shows inline; Remove refuses its
messages again."""

from __future__ import annotations

import orjson

from fleet_protocol import LEGACY_POSITION_TOPIC
from tests.backend.helpers import ProbeRobot, wait_robot
from tests.frontend.console_support import axe_violations, open_page
from tests.support.procs import wait_for


def test_an_admin_registers_and_removes_a_robot_of_the_old_framework(server, page_factory, mqtt_probe) -> None:
    anonymous = mqtt_probe()
    newbot = ProbeRobot(mqtt_probe, "newbot")
    newbot.status()
    page, rec = open_page(page_factory, "/users")
    page.get_by_test_id("legacy-robots").wait_for()

    page.get_by_test_id("legacy-new-id").fill("old-ui")
    page.get_by_test_id("legacy-register").click()
    page.get_by_test_id("legacy-old-ui").filter(has_text="robot/control/commands (shared)").wait_for()
    anonymous.publish(LEGACY_POSITION_TOPIC, orjson.dumps({"robot_id": "old-ui", "position": "1,2,0"}), qos=1)
    with server.client() as c:
        wait_robot(c, "old-ui", lambda r: r["online"] and r["legacy"] and r["position"] is not None)
    page.get_by_test_id("legacy-old-ui").filter(has_text="online").wait_for()  # live, without a reload

    # the API's refusal shows next to the form: a robot online with the agent is not an old one
    with server.client() as c:
        wait_robot(c, "newbot", lambda r: r["online"])
    page.get_by_test_id("legacy-new-id").fill("newbot")
    page.get_by_test_id("legacy-register").click()
    page.get_by_test_id("legacy-error").filter(has_text="online with the agent").wait_for()
    assert page.get_by_test_id("legacy-newbot").count() == 0

    assert axe_violations(page) == []
    page.get_by_test_id("legacy-remove-old-ui").click()
    page.get_by_test_id("legacy-status").filter(has_text="old-ui removed").wait_for()
    assert page.get_by_test_id("legacy-old-ui").count() == 0
    with server.client() as c:
        assert c.get("/api/robots/old-ui").json()["legacy"] is False
        anonymous.publish(LEGACY_POSITION_TOPIC, orjson.dumps({"robot_id": "old-ui", "position": "5,5,0"}), qos=1)

        def refused() -> bool:
            return c.get("/api/health").json()["rejects"]["by_reason"].get("legacy_unregistered", 0) == 1

        wait_for(refused, 5, what="the removed robot's message refused")
    assert [f for f in rec.failures if not f.startswith("409")] == [], rec.failures
