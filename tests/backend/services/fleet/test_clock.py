"""The server's side of the clock sync (backend/services/fleet/clock.py) in a real fleet server on a real broker:
it answers a robot's time/req on that robot's time/resp with its receive and send times, and a bad request
is counted as a reject and changes nothing else."""

from __future__ import annotations

import time
from collections.abc import Callable

import orjson

from fleet_protocol import Topics
from fleet_protocol.clock import decode_time_response
from tests.support.mqtt import MqttProbe
from tests.support.procs import ServerProcess, wait_for

T = Topics()


def test_server_answers_time_requests_and_counts_bad_ones(
    server: ServerProcess, mqtt_probe: Callable[..., MqttProbe]
) -> None:
    probe = mqtt_probe(T.time_resp("r1"), T.time_resp("r2"))
    with server.client() as c:
        for bad in (b"not json", b'{"t0": "x"}', b"[]"):
            probe.publish(T.time_req("r1"), bad, qos=0)
        health = wait_for(
            lambda: (h := c.get("/api/health").json())["rejects"]["by_kind"].get("time/req") == 3 and h,
            10,
            what="3 rejects",
        )
        assert health["rejects"]["by_reason"] == {"bad_json": 1, "bad_time_request": 2}
        # the server kept working: a good request from the same robot is answered, on its own topic only
        t0 = 12345.678
        before = time.time()
        probe.publish(T.time_req("r1"), orjson.dumps({"t0": t0}), qos=0)
        m = probe.wait(lambda m: m.topic == T.time_resp("r1"))
        after = time.time()
        resp = decode_time_response(m.payload)
        assert resp.t0 == t0 and before <= resp.t1 <= resp.t2 <= after
        assert probe.matching(lambda m: m.topic == T.time_resp("r2")) == []
