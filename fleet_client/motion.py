"""Closed-loop motion from a script: goals the robot runs itself (goto, follow_path), single velocity
commands (drive), stopping (cancel) and the site. Part of :class:`~fleet_client.FleetClient`.

    fleet.goto("r1", 0.5, -0.3, wait=True)             # returns the final ack, or raises CommandFailed
    fleet.follow_path("r1", [[0, 0], [1, 0], [1, 1]])  # same
    cmd = fleet.goto("r1", 1, 1, wait=False); ...; fleet.wait_goal(cmd["id"])
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from fleet_client.errors import CommandFailed

#: How long ``wait=True`` waits for a goal without ``timeout_s`` (the robot's own timeout ends it sooner:
#: 15 s + 3x the time the distance needs at its speed).
DEFAULT_GOAL_WAIT_S = 900.0
#: Margin over a goal's ``timeout_s`` for its final ack to travel back.
ACK_MARGIN_S = 10.0
#: What ``?wait`` may wait on the server per request (the route's cap).
SERVER_WAIT_MAX_S = 10.0
GOAL_FINAL = frozenset({"done", "failed", "aborted", "rejected", "expired"})


def _without_none(**kw: Any) -> dict[str, Any]:
    return {k: v for k, v in kw.items() if v is not None}


class MotionMixin:
    """Goals, drive, cancel and the site; mixed into FleetClient (it needs its request methods)."""

    if TYPE_CHECKING:

        def send_command(
            self,
            robot_id: str,
            command: str,
            args: dict[str, Any] | None = None,
            *,
            wait: float | None = 5.0,
            ttl_s: float | None = None,
            source: str = "fleet-client",
        ) -> dict[str, Any]: ...

        def command(self, command_id: str) -> dict[str, Any]: ...

        def _get(self, path: str, **params: Any) -> Any: ...

    def site(self) -> dict[str, Any]:
        """The site the server holds (``boundary``, ``version`` and, where the server has them, keep-outs,
        base stations and the wall ``tags``)."""
        result: dict[str, Any] = self._get("/api/site")
        return result

    def goto(
        self,
        robot_id: str,
        x: float,
        y: float,
        yaw: float | None = None,
        *,
        tolerance_m: float = 0.05,
        max_speed: float | None = None,
        timeout_s: float | None = None,
        wait: bool = True,
        wait_timeout: float | None = None,
    ) -> dict[str, Any]:
        """Drive to (x, y) [and turn to ``yaw``] with the robot's own controller. ``wait``: returns the
        command once its final ack is ``done``; raises :class:`CommandFailed` when it ends otherwise
        (``failed`` with a reason, ``aborted``, ``rejected``) or no final ack came within ``wait_timeout``.
        Without ``wait``: the command as sent (then :meth:`wait_goal`)."""
        args = _without_none(x=x, y=y, yaw=yaw, tolerance_m=tolerance_m, max_speed=max_speed, timeout_s=timeout_s)
        return self._goal(robot_id, "goto", args, wait, wait_timeout, timeout_s)

    def follow_path(
        self,
        robot_id: str,
        waypoints: Sequence[Sequence[float]],
        *,
        tolerance_m: float = 0.05,
        max_speed: float | None = None,
        loop: bool = False,
        timeout_s: float | None = None,
        wait: bool = True,
        wait_timeout: float | None = None,
    ) -> dict[str, Any]:
        """Follow the polyline through ``waypoints`` ([[x, y], ...], up to 500); ``loop``: forever (or
        until ``timeout_s``, a stop or another motion), so it cannot be waited for without a timeout."""
        if loop and wait and timeout_s is None:
            raise ValueError("a looping path without timeout_s never ends: pass wait=False (then cancel())")
        points = [[float(p[0]), float(p[1])] for p in waypoints]
        args = _without_none(
            waypoints=points, tolerance_m=tolerance_m, max_speed=max_speed, loop=loop, timeout_s=timeout_s
        )
        return self._goal(robot_id, "follow_path", args, wait, wait_timeout, timeout_s)

    def drive(
        self, robot_id: str, linear: float, angular: float = 0.0, *, duration_s: float = 0.5, wait: float | None = None
    ) -> dict[str, Any]:
        """One velocity command (m/s, rad/s) for ``duration_s`` (its deadman). For continuous control use
        :meth:`~fleet_client.FleetClient.control`, which renews it. ``wait`` as for send_command."""
        args = {"linear": linear, "angular": angular, "duration_s": duration_s}
        return self.send_command(robot_id, "drive", args, wait=wait)

    def cancel(self, robot_id: str, wait: float | None = 5.0) -> dict[str, Any]:
        """Stop the robot: ends a goal (acked ``aborted``), a path or a drive at once."""
        return self.send_command(robot_id, "stop", {}, wait=wait)

    def wait_goal(self, command_id: str, timeout: float = DEFAULT_GOAL_WAIT_S, interval: float = 0.1) -> dict[str, Any]:
        """Wait for a goal's final ack: the command when ``done``, else :class:`CommandFailed`."""
        deadline = time.monotonic() + timeout
        cmd = self.command(command_id)
        while cmd["status"] not in GOAL_FINAL and time.monotonic() < deadline:
            time.sleep(interval)
            cmd = self.command(command_id)
        if cmd["status"] != "done":
            if cmd["status"] not in GOAL_FINAL:
                cmd = {**cmd, "status": "timeout", "reason": f"no final ack within {timeout:g} s ({cmd['status']})"}
            raise CommandFailed(cmd)
        return cmd

    def _goal(
        self,
        robot_id: str,
        name: str,
        args: dict[str, Any],
        wait: bool,
        wait_timeout: float | None,
        timeout_s: float | None,
    ) -> dict[str, Any]:
        if not wait:
            return self.send_command(robot_id, name, args, wait=None)
        limit = wait_timeout or (timeout_s + ACK_MARGIN_S if timeout_s else DEFAULT_GOAL_WAIT_S)
        started = time.monotonic()
        cmd = self.send_command(robot_id, name, args, wait=min(SERVER_WAIT_MAX_S, limit))
        if cmd["status"] in GOAL_FINAL:
            if cmd["status"] != "done":
                raise CommandFailed(cmd)
            return cmd
        return self.wait_goal(cmd["id"], max(0.0, limit - (time.monotonic() - started)))
