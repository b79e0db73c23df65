"""The exceptions a script gets from :class:`~fleet_client.FleetClient`."""

from __future__ import annotations

from typing import Any


class FleetError(Exception):
    """An HTTP error from the server (``status_code``, ``detail``) or a connection problem (status 0)."""

    def __init__(self, status_code: int, detail: str, body: Any = None) -> None:
        super().__init__(f"{status_code}: {detail}" if status_code else detail)
        self.status_code = status_code
        self.detail = detail
        self.body = body

    @property
    def code(self) -> str | None:
        """The server's machine-readable ``code`` (``estop_engaged``, ``lease_held``, ...) when it sent one."""
        return self.body.get("code") if isinstance(self.body, dict) else None


class CommandFailed(FleetError):
    """A goal (or any command waited for) did not end ``done``: ``status`` is its final status (failed,
    aborted, rejected, expired, or timeout when none came in time), ``reason`` the robot's reason and
    ``failure`` its first word (``timeout``, ``no_position``, ``geofence``, ``stalled``, ``unsupervised``,
    ``link_lost``...); ``command`` is the whole record with its acks."""

    def __init__(self, command: dict[str, Any]) -> None:
        self.command = command
        self.status: str = command.get("status", "")
        self.reason: str = command.get("reason", "") or ""
        self.failure = self.reason.split(":", 1)[0].strip() if self.reason else self.status
        what = f"{command.get('command', 'command')} {command.get('id', '')} to {command.get('robot_id', '?')}"
        super().__init__(0, f"{what} {self.status}" + (f": {self.reason}" if self.reason else ""), command)


class MissionFailed(FleetError):
    """A mission waited for (:meth:`~fleet_client.FleetClient.wait_mission`) ended otherwise: ``state`` is
    ``aborted`` or ``failed`` (or ``timeout`` when it was still going), ``reason`` the server's reason;
    ``mission`` the whole record with its transitions and events."""

    def __init__(self, mission: dict[str, Any], timed_out: float | None = None) -> None:
        self.mission = mission
        self.state: str = "timeout" if timed_out is not None else mission.get("state", "")
        self.reason: str = mission.get("reason", "") or ""
        what = f"mission {mission.get('id', '?')}"
        if timed_out is not None:
            text = f"{what} still {mission.get('state')} after {timed_out:g} s" + (
                f" ({self.reason})" if self.reason else ""
            )
            # where each robot is, and the last events: what a script's log needs to say why
            robots = ", ".join(_robot_state(r) for r in mission.get("robots", []))
            events = [f"{e.get('kind')} {e.get('robot_id') or ''}".strip() for e in mission.get("events", [])[-5:]]
            text += f"; robots: {robots or 'none'}; last events: {', '.join(events) or 'none'}"
        else:
            text = f"{what} {self.state}" + (f": {self.reason}" if self.reason else "")
        super().__init__(0, text, mission)


def _robot_state(robot: Any) -> str:
    """A mission's robot as a draft lists it (its id) or as a started one does (id and status)."""
    if isinstance(robot, dict):
        return f"{robot.get('robot_id')}: {robot.get('status')}"
    return str(robot)


class ControlError(FleetError):
    """An off-board controller cannot go on: the robot was refused to it (``code`` estop_engaged,
    robot_held, lease_held, robot_offline, ...), sent no pose in time (no_position) or the socket broke
    (connection_lost)."""

    def __init__(self, code: str, detail: str) -> None:
        super().__init__(0, f"{code}: {detail}", {"code": code, "detail": detail})
