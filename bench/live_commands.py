"""The REST command loop of bench_live.py: ``stop`` with ``?wait`` through two clients, timed by stage."""

from __future__ import annotations

import time
from typing import Any

import httpx
import orjson

from bench.common import percentile
from bench.rawhttp import RawHttpClient

#: the stages of a command's round trip, from the command's and its acks' time stamps (one clock: all
#: processes run on this machine): request in -> command created -> agent's done ack -> server has it -> reply
RTT_STAGES = ("http_in", "to_agent_done", "ack_to_server", "reply_out")
#: the REST clients the command loop takes turns with: a lean one (bench/rawhttp.py: the system's round
#: trip) and httpx (what a researcher's script sees, with ~1-1.5 ms of its own Python per request)
CLIENTS = ("lean", "httpx")


def command_loop(base_url: str, headers: dict[str, str], robot_ids: list[str], stop_at: float) -> list[tuple[Any, ...]]:
    """``stop`` with ``?wait`` every 50 ms, the two clients taking turns (each robot gets both):
    (client, round trip, *RTT_STAGES) per command acked ``done``, in seconds."""
    rtts: list[tuple[Any, ...]] = []
    url = httpx.URL(base_url)
    lean = RawHttpClient(url.host, url.port or 80, headers)
    body = orjson.dumps({"command": "stop", "source": "bench"})
    with httpx.Client(base_url=base_url, headers=headers, timeout=10) as c:
        i = 0
        while time.monotonic() < stop_at:
            client = CLIENTS[i % 2]
            rid = robot_ids[(i // 2) % len(robot_ids)]
            path = f"/api/robots/{rid}/commands?wait=2"
            t, sent = time.perf_counter(), time.time()
            if client == "lean":
                status, raw = lean.post_json(path, body)
            else:
                r = c.post(path, content=body, headers={"Content-Type": "application/json"})
                status, raw = r.status_code, r.content
            rtt, replied = time.perf_counter() - t, time.time()
            reply = orjson.loads(raw) if status == 200 else {}
            if reply.get("status") == "done":
                done = next(a for a in reply["acks"] if a["status"] == "done")
                rtts.append(
                    (
                        client,
                        rtt,
                        reply["ts"] - sent,
                        done["ts"] - reply["ts"],
                        done["received_ts"] - done["ts"],
                        replied - done["received_ts"],
                    )
                )
            i += 1
            time.sleep(0.05)
    lean.close()
    return rtts


def command_process(base_url: str, headers: dict[str, str], robot_ids: list[str], seconds: float, out: Any) -> None:
    """The REST client in a process of its own, as a researcher's script is: in the bench process its
    thread would wait for the GIL behind the WebSocket clients' frames (10,000 a second with spread
    arrivals), which the server's round trip does not include."""
    out.extend(command_loop(base_url, headers, robot_ids, time.monotonic() + seconds))


def command_figures(rows: list[tuple[Any, ...]]) -> dict[str, Any]:
    """p50/p99 and the stages' p50 per client, in ms: ``cmd_*`` for the lean client, ``cmd_httpx_*``."""
    out: dict[str, Any] = {}
    for client in CLIENTS:
        mine = [row[1:] for row in rows if row[0] == client]
        key = "cmd" if client == "lean" else f"cmd_{client}"
        out[f"{key}_p50_ms"] = percentile([m[0] for m in mine], 50) * 1000
        out[f"{key}_p99_ms"] = percentile([m[0] for m in mine], 99) * 1000
        out[f"{key}_commands"] = len(mine)
        out[f"{key}_stages_p50_ms"] = {
            name: percentile([m[k + 1] for m in mine], 50) * 1000 for k, name in enumerate(RTT_STAGES)
        }
    return out
