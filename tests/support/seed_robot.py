"""A test client that behaves exactly like a robot on the seed's framework (its ``main.py``).

It connects anonymously with paho's defaults (MQTT 3.1.1, clean session), subscribes to the shared
``robot/control/commands`` (or, for a robot changed to listen on its own topic, ``{id}/control/commands``),
and drives on every drive string until it hears ``"stop"``: it has no deadman and no e-stop of its own.
It publishes its Lighthouse position on ``robot/sensor_data/position`` as the seed does, so the server
sees it. Every command it hears is recorded with the time it arrived.
"""

from __future__ import annotations

import json
import threading
import time
import uuid
from dataclasses import dataclass

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from fleet_protocol import (
    DRIVE_COMMANDS,
    LEGACY_COMMAND_TOPIC,
    LEGACY_POSITION_TOPIC,
    legacy_namespaced_command_topic,
)
from tests.support.procs import wait_for


@dataclass(frozen=True)
class Heard:
    at: float
    topic: str
    command: str
    qos: int


class SeedRobot:
    def __init__(self, host: str, port: int, robot_id: str, own_topic: bool = False) -> None:
        self.robot_id = robot_id
        self.topic = legacy_namespaced_command_topic(robot_id) if own_topic else LEGACY_COMMAND_TOPIC
        self.heard: list[Heard] = []
        self.driving: str | None = None  # the seed drives until "stop"
        self._lock = threading.Lock()
        self._subscribed = threading.Event()
        self.c = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"seed-{robot_id}-{uuid.uuid4().hex[:6]}")
        self.c.on_connect = lambda c, *_: c.subscribe(self.topic)
        self.c.on_subscribe = lambda *_: self._subscribed.set()
        self.c.on_message = self._on_message
        self.c.connect(host, port, 60)
        self.c.loop_start()
        assert self._subscribed.wait(10), "seed robot not subscribed"

    def _on_message(self, client: mqtt.Client, userdata: object, msg: mqtt.MQTTMessage) -> None:
        command = msg.payload.decode(errors="replace")
        with self._lock:
            self.heard.append(Heard(time.time(), msg.topic, command, msg.qos))
            if command == "stop":
                self.driving = None
            elif command in DRIVE_COMMANDS:
                self.driving = command

    def publish_position(self, x: float = 0.0, y: float = 0.0) -> None:
        payload = json.dumps({"robot_id": self.robot_id, "position": f"{x},{y},0"})
        self.c.publish(LEGACY_POSITION_TOPIC, payload, qos=0)

    def commands(self, since: float = 0.0) -> list[Heard]:
        with self._lock:
            return [h for h in self.heard if h.at >= since]

    def wait_heard(self, command: str, since: float, timeout: float = 10.0) -> Heard:
        def first() -> Heard | None:
            return next((h for h in self.commands(since) if h.command == command), None)

        return wait_for(first, timeout, what=f"{self.robot_id} hears {command!r}")

    def close(self) -> None:
        self.c.disconnect()
        self.c.loop_stop()
