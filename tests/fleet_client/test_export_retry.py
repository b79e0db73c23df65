"""``fleet_client`` honours Retry-After: an export refused for now (429, the client already runs its most)
is asked again after the wait the server names, a bounded number of times, against a real server."""

from __future__ import annotations

import io
import threading

from fleet_client import FleetClient, FleetError
from tests.support.exports import BIG_ROWS, big_robot, exports, started, unread
from tests.support.procs import wait_for


def test_an_export_refused_for_now_is_retried_after_the_wait(broker, database_url, workdir, mqtt_probe):
    # one export per client; the held one is never cut off while the test runs (it ends when closed)
    env = {"FLEET_EXPORT_MAX_PER_CLIENT": "1", "FLEET_EXPORT_RETRY_AFTER_S": "1"}
    env["FLEET_EXPORT_STALL_TIMEOUT_S"] = "3600"
    with started(broker, database_url, workdir, **env) as server:
        big_robot(server, mqtt_probe, database_url)
        holder = unread(server)  # the same client's other download, left unread: its one slot is taken
        with server.client() as c:
            wait_for(lambda: exports(c)["running"] == 1, 30, what="the held export")
            with FleetClient(server.base_url, server.token, retries=0) as impatient:
                try:
                    impatient.export(io.BytesIO(), "big", "blob")
                    raise AssertionError("the second export of a client allowed one should be refused")
                except FleetError as exc:
                    assert exc.status_code == 429

            def finish_once_refused_again() -> None:  # the holder gives up once the retrying client was refused
                wait_for(lambda: exports(c)["refused_client"] >= 2, 30, what="the client refused")
                holder.close()

            closer = threading.Thread(target=finish_once_refused_again)
            closer.start()
            try:
                out = io.BytesIO()
                with FleetClient(server.base_url, server.token) as fleet:
                    headers = fleet.export(out, "big", "blob")
            finally:
                closer.join(30)
                holder.close()
            assert headers["x-fleet-method"] == "none" and out.getvalue().count(b"\n") == BIG_ROWS + 1
            assert exports(c)["refused_client"] >= 2 and exports(c)["admitted"] == 2  # (more: a slow machine)
