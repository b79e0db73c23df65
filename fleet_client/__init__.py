"""A small Python client for the Mollusca Fleet server (``fleet-client`` is its command line).

Only httpx and the standard library; live streaming and ``control`` also need ``websockets``.
Authentication: pass ``token=`` (or set ``FLEET_TOKEN``); every request then carries
``Authorization: Bearer <token>``.

    from fleet_client import FleetClient
    with FleetClient("http://127.0.0.1:8000", token="...") as fleet:
        print(fleet.robots())
        fleet.goto("r1", 0.5, -0.3)                       # waits for "done"; CommandFailed otherwise
        rows = list(fleet.history_rows("r1", start="2025-01-01T10:00", end="2025-01-01T10:05"))

    async with fleet.control("r1") as ctl:                # an off-board controller (docs/autonomy.md)
        async for pose in ctl.poses():
            await ctl.drive(0.1, -0.5 * pose["y"])
"""

from fleet_client.client import DEFAULT_URL, FINAL_STATUSES, FleetClient
from fleet_client.control import RobotControl
from fleet_client.errors import CommandFailed, ControlError, FleetError, MissionFailed

__all__ = [
    "DEFAULT_URL",
    "FINAL_STATUSES",
    "CommandFailed",
    "ControlError",
    "FleetClient",
    "FleetError",
    "MissionFailed",
    "RobotControl",
]
__version__ = "0.1.0"
