"""A small Python client for the Mollusca Fleet server (``fleet-client`` is its command line).

Only httpx and the standard library; live streaming also needs ``websockets``. Authentication: pass
``token=`` (or set ``FLEET_TOKEN``); every request then carries ``Authorization: Bearer <token>``.

    from fleet_client import FleetClient
    with FleetClient("http://127.0.0.1:8000", token="...") as fleet:
        print(fleet.robots())
        cmd = fleet.send_command("r1", "move_forward", {"speed": 0.5, "duration_s": 1}, wait=5)
        rows = list(fleet.history_rows("r1", start="2025-01-01T10:00", end="2025-01-01T10:05"))
"""

from fleet_client.client import DEFAULT_URL, FINAL_STATUSES, FleetClient, FleetError

__all__ = ["DEFAULT_URL", "FINAL_STATUSES", "FleetClient", "FleetError"]
__version__ = "0.1.0"
