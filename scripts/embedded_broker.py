"""A pure-Python MQTT broker (amqtt) for `make demo` on machines without Mosquitto.

Good enough for a demo fleet: MQTT 3.1.1, QoS 0/1, retained messages, Last Will (the agent's offline
status) — tests/scripts/test_embedded_broker.py checks each with paho, the client the fleet uses. For a
lab use Mosquitto (deploy/mosquitto/). Usage: python scripts/embedded_broker.py [--host H] [--port P]
Stops cleanly on SIGINT / SIGTERM.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
from typing import Any


async def serve(host: str, port: int) -> None:
    from amqtt.broker import Broker

    config: dict[str, Any] = {
        "listeners": {"default": {"type": "tcp", "bind": f"{host}:{port}", "max_connections": 1000}},
        "plugins": {
            "amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True},
        },
    }
    broker = Broker(config)
    await broker.start()
    print(f"embedded broker listening on {host}:{port}", flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    await stop.wait()
    await broker.shutdown()


def main() -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--host", default="0.0.0.0")
    p.add_argument("--port", type=int, default=1883)
    args = p.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        import amqtt  # noqa: F401
    except ImportError:
        print(
            "embedded broker: amqtt is not installed (pip install -e '.[demo]'), or install mosquitto", file=sys.stderr
        )
        return 1
    asyncio.run(serve(args.host, args.port))
    return 0


if __name__ == "__main__":
    sys.exit(main())
