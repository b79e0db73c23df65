"""``fleet-server serve``: how the HTTP server treats its connections."""

from __future__ import annotations

import http.client
import time

from tests.support.procs import ServerProcess


def test_an_idle_keep_alive_connection_outlives_a_clients_own_expiry(server: ServerProcess) -> None:
    """httpx drops an idle connection after 5 s; uvicorn's default closes it after 5 s as well, and a client
    pausing about that long then sent on a connection the server was closing ("Server disconnected without
    sending a response", seen in a mission test). The server keeps it well past that."""
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=10)
    try:
        conn.request("GET", "/api/health")
        first = conn.getresponse()
        first.read()
        assert first.status == 200 and not first.will_close
        sock = conn.sock
        time.sleep(6.0)  # past both 5 s expiries
        conn.request("GET", "/api/health")  # on the same socket: the client has not seen it close
        assert conn.sock is sock
        again = conn.getresponse()  # RemoteDisconnected when the server has closed it
        assert again.status == 200 and again.read()
    finally:
        conn.close()
