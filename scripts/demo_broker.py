"""The demo's broker (scripts/demo.py): Mosquitto with the lab's queue and persistence settings, and the
MQTT round trip that checks whichever broker runs.

A broker that queues differently from the lab's hides loss the lab would see (or the other way round):
the demo's Mosquitto takes every queue, in-flight and persistence setting from
deploy/mosquitto/mosquitto.conf, and only differs where a demo must (anonymous access, its port, its
data directory under .demo/). tests/scripts/test_demo_broker.py checks it against a real Mosquitto.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import threading
import uuid
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

#: The lab's broker config; the demo's Mosquitto takes its queue, in-flight and persistence settings from it,
#: so that the demo queues (and, past the queue, drops) exactly like the lab.
SHIPPED_MOSQUITTO_CONF = ROOT / "deploy" / "mosquitto" / "mosquitto.conf"
SHARED_BROKER_SETTINGS = (
    "persistence",
    "autosave_interval",
    "persistent_client_expiration",
    "max_queued_messages",
    "max_inflight_messages",
    "max_packet_size",
    "set_tcp_nodelay",
)


def shipped_broker_settings(conf: Path = SHIPPED_MOSQUITTO_CONF) -> list[str]:
    """The SHARED_BROKER_SETTINGS lines of the lab's mosquitto.conf, as written there."""
    lines = [ln.strip() for ln in conf.read_text().splitlines() if ln.split(" ", 1)[0] in SHARED_BROKER_SETTINGS]
    missing = set(SHARED_BROKER_SETTINGS) - {ln.split(" ", 1)[0] for ln in lines}
    if missing:
        raise RuntimeError(f"{conf} no longer sets {sorted(missing)}")
    return lines


def demo_mosquitto_conf(port: int, data_dir: Path, host: str = "127.0.0.1") -> str:
    """The demo's Mosquitto: anonymous (demo only), on ``host`` (this machine only unless the demo runs with
    ``--lan``: then every interface, "0.0.0.0"), the lab's queue and persistence.
    Started by root, Mosquitto would switch to its own user, which cannot write a data directory under
    root's home or a private temporary directory: the demo's broker stays the user who runs the demo."""
    return (
        "# written by scripts/demo.py; the lab configuration is deploy/mosquitto/mosquitto.conf, and the\n"
        "# queue, in-flight and persistence settings below are copied from it\n"
        f"listener {port} {host}\n"  # --lan: every interface, so robots on the LAN connect here
        "allow_anonymous true\n"  # demo only: no credentials
        + "".join(f"{line}\n" for line in shipped_broker_settings())
        + f"persistence_location {data_dir}/\n"
        + ("user root\n" if os.geteuid() == 0 else "")
    )


def broker_data_dir(demo_dir: Path) -> Path:
    """Where the demo's Mosquitto saves its state: ``demo_dir``/mosquitto-data."""
    data = demo_dir / "mosquitto-data"
    data.mkdir(parents=True, exist_ok=True)
    return data


def mosquitto_binary() -> str | None:
    exe = shutil.which("mosquitto")
    if exe:
        return exe
    return "/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").exists() else None


def mqtt_round_trip(port: int, timeout: float = 3.0) -> bool:
    """A real MQTT check of the broker: connect, publish a retained QoS 1 message, read it back from a
    second connection (the retained copy), then clear it. True when all of that worked."""
    import paho.mqtt.client as mqtt

    topic = f"fleet-demo-check/{uuid.uuid4().hex[:8]}"
    payload = b"ok"
    got = threading.Event()
    clients: list[mqtt.Client] = []

    def client(name: str) -> mqtt.Client:
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"demo-check-{name}-{uuid.uuid4().hex[:6]}")
        clients.append(c)
        c.connect("127.0.0.1", port, keepalive=10)
        c.loop_start()
        return c

    try:
        pub = client("pub")
        pub.publish(topic, payload, qos=1, retain=True).wait_for_publish(timeout)  # PUBACK: QoS 1 works
        sub = client("sub")

        def on_message(_c: Any, _u: Any, msg: Any) -> None:
            if msg.topic == topic and msg.payload == payload and msg.retain:
                got.set()

        sub.on_message = on_message
        sub.subscribe(topic, qos=1)
        ok = got.wait(timeout)
        pub.publish(topic, b"", qos=1, retain=True).wait_for_publish(timeout)  # clear the retained message
        return ok
    except (OSError, RuntimeError, ValueError):
        return False
    finally:
        for c in clients:
            with contextlib.suppress(Exception):
                c.disconnect()
                c.loop_stop()
