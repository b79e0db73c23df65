"""One message to the broker, confirmed: what ``fleet-agent estop`` needs (it runs without the server).

MQTT 3.1.1 acknowledges a publish the broker's ACL drops, so a PUBACK proves nothing. The message counts
as delivered only once it comes back on a subscription to its own topic (the e-stop account may read the
e-stop), byte for byte.
"""

from __future__ import annotations

import threading
import uuid
from dataclasses import dataclass
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode


@dataclass(frozen=True, slots=True)
class BrokerLogin:
    host: str
    port: int
    username: str | None = None
    password: str | None = None
    tls: bool = False
    tls_ca: str | None = None


def publish_confirmed(
    login: BrokerLogin, topic: str, payload: bytes, *, qos: int, retain: bool, timeout_s: float = 5.0
) -> str | None:
    """Publish and wait for the copy the broker delivers back. None when confirmed, else what went wrong."""
    connected = threading.Event()
    subscribed = threading.Event()
    echoed = threading.Event()
    problem: list[str] = []
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"fleet-estop-{uuid.uuid4().hex[:8]}")
    if login.username is not None:
        client.username_pw_set(login.username, login.password)
    if login.tls:
        client.tls_set(ca_certs=login.tls_ca)

    def on_connect(c: mqtt.Client, _u: object, _f: object, rc: object, _p: object) -> None:
        if getattr(rc, "is_failure", False):
            problem.append(f"broker refused the connection: {rc}")
        else:
            c.subscribe(topic, qos=qos)
        connected.set()

    def on_subscribe(_c: mqtt.Client, _u: Any, _m: int, codes: list[ReasonCode], _p: Properties) -> None:
        if any(getattr(rc, "is_failure", False) for rc in codes):
            problem.append(f"broker refused the subscription to {topic}")
        subscribed.set()

    def on_message(_c: object, _u: object, msg: mqtt.MQTTMessage) -> None:
        if msg.topic == topic and bytes(msg.payload) == payload:
            echoed.set()

    client.on_connect = on_connect
    client.on_subscribe = on_subscribe
    client.on_message = on_message
    try:
        client.connect(login.host, login.port, keepalive=10)
    except OSError as exc:
        return f"cannot reach the broker at {login.host}:{login.port}: {exc}"
    client.loop_start()
    try:
        if not connected.wait(timeout_s):
            return f"no answer from the broker at {login.host}:{login.port} within {timeout_s}s"
        if problem:
            return problem[0]
        if not subscribed.wait(timeout_s) or problem:
            return problem[0] if problem else f"no SUBACK for {topic} within {timeout_s}s"
        info = client.publish(topic, payload, qos=qos, retain=retain)
        info.wait_for_publish(timeout_s)
        if not echoed.wait(timeout_s):
            return (
                f"the broker did not deliver the message on {topic} within {timeout_s}s "
                f"(is {login.username or 'this account'} allowed to publish there?)"
            )
        return None
    finally:
        client.disconnect()
        client.loop_stop()
