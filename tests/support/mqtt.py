"""A small paho client for tests: publish raw payloads and collect what arrives."""

from __future__ import annotations

import contextlib
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass

import orjson
import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion


@dataclass
class Received:
    topic: str
    payload: bytes
    retain: bool
    at: float

    def json(self) -> object:
        return orjson.loads(self.payload)


class MqttProbe:
    def __init__(
        self,
        host: str,
        port: int,
        subscriptions: list[str] | None = None,
        client_id: str | None = None,
        clean_session: bool = True,
        username: str | None = None,
        password: str | None = None,
    ) -> None:
        self.messages: list[Received] = []
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._subs = list(subscriptions or [])
        self._connected = threading.Event()
        #: message ids of the SUBSCRIBEs the broker has acknowledged (SUBACK), and those sent on connect
        self._subacked: set[int] = set()
        self._connect_mids: list[int] = []
        self.client = mqtt.Client(
            CallbackAPIVersion.VERSION2,
            client_id=client_id or f"probe-{uuid.uuid4().hex[:8]}",
            clean_session=clean_session,
        )
        if username is not None:
            self.client.username_pw_set(username, password)
        self.client.on_connect = self._on_connect
        self.client.on_message = self._on_message
        self.client.on_subscribe = self._on_subscribe
        self.client.connect(host, port, keepalive=30)
        self.client.loop_start()
        if not self._connected.wait(10):
            raise AssertionError("test MQTT probe could not connect")
        for mid in list(self._connect_mids):
            self._wait_suback(mid)

    def _on_connect(self, client: mqtt.Client, userdata: object, flags: object, rc: object, props: object) -> None:
        self._connect_mids = [client.subscribe(s, qos=1)[1] for s in self._subs]
        self._connected.set()

    def _on_subscribe(
        self, client: mqtt.Client, userdata: object, mid: int, reason_codes: object, props: object
    ) -> None:
        with self._cond:
            self._subacked.add(mid)
            self._cond.notify_all()

    def _wait_suback(self, mid: int, timeout: float = 10.0) -> None:
        """The broker has the subscription once it acknowledged it: a publish after this reaches us."""
        with self._cond:
            if not self._cond.wait_for(lambda: mid in self._subacked, timeout):
                raise AssertionError(f"no SUBACK for subscribe mid {mid} within {timeout} s")

    def subscribe(self, topic: str) -> None:
        self._subs.append(topic)
        result, mid = self.client.subscribe(topic, qos=1)
        assert result == mqtt.MQTT_ERR_SUCCESS
        self._wait_suback(mid)  # the caller may rely on the subscription from now on

    def _on_message(self, client: mqtt.Client, userdata: object, msg: mqtt.MQTTMessage) -> None:
        with self._cond:
            self.messages.append(Received(msg.topic, bytes(msg.payload), bool(msg.retain), time.time()))
            self._cond.notify_all()

    def publish(self, topic: str, payload: bytes | str, qos: int = 1, retain: bool = False) -> None:
        info = self.client.publish(topic, payload, qos=qos, retain=retain)
        info.wait_for_publish(10)

    def wait(self, predicate: Callable[[Received], bool], timeout: float = 10.0) -> Received:
        deadline = time.monotonic() + timeout
        seen = 0
        with self._cond:
            while True:
                for m in self.messages[seen:]:
                    if predicate(m):
                        return m
                seen = len(self.messages)
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise AssertionError(f"no matching MQTT message within {timeout}s; got {len(self.messages)}")
                self._cond.wait(remaining)

    def matching(self, predicate: Callable[[Received], bool]) -> list[Received]:
        with self._lock:
            return [m for m in self.messages if predicate(m)]

    def close(self) -> None:
        self.client.disconnect()
        # paho's race: its network thread clears ``_thread`` as its loop returns after the DISCONNECT, between
        # loop_stop's check and its join (AttributeError, seen in CI): the thread has ended, all that is wanted
        with contextlib.suppress(AttributeError):
            self.client.loop_stop()
