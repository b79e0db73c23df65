"""``fleet-server`` warns when the broker's ACL keeps the fleet poses from the robots (a lab that upgraded and kept
its old ACL): a real Mosquitto with authentication on and the shipped ACL without the poses lines, the real
server logged in as ``fleet-server``. Its own poses come back (its ``fleet/#``), but a robot hears none and says
so on its avoidance stream: one WARNING with the line to add. An ACL that keeps the server from the topic too:
its own poses never come back, and it warns within ``FLEET_POSES_ACL_CHECK_S`` of connecting."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import orjson

from fleet_protocol import Topics, encode_telemetry
from tests.deploy.test_mosquitto import DEPLOY, Client, _passwd, shipped_broker
from tests.support.procs import ServerProcess, wait_for

T = Topics()
USERS = {"fleet-server": "pw-server", "snail-1": "pw-1"}
POSES_LINE = "pattern read fleet/poses\n"
CHECK_S = 1.0


class _Broker:
    """What ServerProcess reads of a broker (the server's URL carries its credentials)."""

    def __init__(self, port: int) -> None:
        self.host, self.port = "127.0.0.1", port
        self.url = f"mqtt://fleet-server:pw-server@127.0.0.1:{port}"


def _old_acl(extra_server_lines: str = "") -> str:
    """The shipped ACL as it was before the poses (what a lab that upgrades still has)."""
    acl = (DEPLOY / "mosquitto" / "acl.example").read_text()
    assert POSES_LINE in acl
    acl = acl.replace(POSES_LINE, "")
    return acl.replace("user fleet-server\n", f"user fleet-server\n{extra_server_lines}", 1)


@contextmanager
def _server(port: int, tmp_path: Path) -> Iterator[ServerProcess]:
    """The real server on the broker at ``port``, logged in as ``fleet-server``, checking its poses quickly."""
    server = ServerProcess(
        _Broker(port),  # type: ignore[arg-type]
        f"sqlite:///{tmp_path / 'fleet.db'}",
        tmp_path,
        FLEET_POSES_ACL_CHECK_S=str(CHECK_S),
    )
    server.start()
    try:
        yield server
    finally:
        server.stop()


def _all_stats(server: ServerProcess) -> dict[str, Any]:
    with server.client() as c:
        return c.get("/api/stats").json()  # type: ignore[no-any-return]


def _stats(server: ServerProcess) -> dict[str, Any]:
    return _all_stats(server)["poses"]  # type: ignore[no-any-return]


def _warnings(server: ServerProcess) -> list[str]:
    return [line for line in server.output().splitlines() if "WARNING" in line and "pattern read fleet/poses" in line]


def test_a_robot_that_hears_no_poses_under_an_old_acl_makes_the_server_warn(tmp_path: Path) -> None:
    with shipped_broker("auth", {"passwd": _passwd(USERS), "acl": _old_acl()}) as b:
        robot = Client(b.port, username="snail-1", password="pw-1", subscribe=(T.poses(),))
        robot.wait_connected()
        try:
            with _server(b.port, tmp_path) as server:
                status = {"online": True, "ts": time.time(), "capabilities": {"sensors": ["position"], "commands": []}}
                robot.publish(T.status("snail-1"), orjson.dumps(status), retain=True)
                wait_for(lambda: _stats(server)["own_heard"] > 5, 10, what="the server hears its own poses")
                assert robot.got == []  # ... and the robot none of them
                assert _stats(server)["acl_problem"] is None and _warnings(server) == []
                time.sleep(CHECK_S)  # the robot has been online long enough to have heard some
                report = {"event": "active", "cause": "no_poses", "linear": 0.1, "filtered_linear": 0.03}
                robot.publish(T.telemetry("snail-1", "avoidance"), encode_telemetry(0, report))
                problem = wait_for(lambda: _stats(server)["acl_problem"], 10, what="the ACL problem")
                assert "robot snail-1 hears no fleet poses" in problem
                robot.publish(T.telemetry("snail-1", "avoidance"), encode_telemetry(1, report))

                def second_report_taken() -> bool:
                    return _all_stats(server)["streams"].get("snail-1", {}).get("avoidance", {}).get("count") == 2

                wait_for(second_report_taken, 10, what="the second report")
                assert len(_warnings(server)) == 1 and _stats(server)["acl_warnings"] == 1  # once per robot
        finally:
            robot.close()


def test_a_server_whose_own_poses_never_come_back_warns_soon_after_connecting(tmp_path: Path) -> None:
    acl = _old_acl("topic deny fleet/poses\n")
    with shipped_broker("auth", {"passwd": _passwd(USERS), "acl": acl}) as b, _server(b.port, tmp_path) as server:
        problem = wait_for(lambda: _stats(server)["acl_problem"], 10, what="the ACL problem")
        assert "did not deliver this server's own fleet poses" in problem
        stats = _stats(server)
        assert stats["sent"] > 0 and stats["own_heard"] == 0
        # another check period of publishes (each one checks again): still the one warning
        sent = stats["sent"]
        wait_for(lambda: _stats(server)["sent"] >= sent + 2 * CHECK_S / 0.1, 10, what="a check period's publishes")
        assert len(_warnings(server)) == 1  # once per connection
