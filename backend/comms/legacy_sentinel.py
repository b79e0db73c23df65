"""The legacy sentinel: stops robots on the old framework when their server goes silent.

Robots on the seed's framework drive until they hear ``"stop"``. The server stops them on a clean shutdown
and its Last Will does on a crash, but a *partitioned* (or frozen) server is noticed by the broker only
after its keepalive check, which Mosquitto 2.0 runs in whole seconds: 3.8 s with a 1 s keepalive on this
project's test machine (docs/safety.md). The sentinel runs beside the broker (same host, loopback), listens
to every server's heartbeat (``{prefix}/heartbeat``, several a second), and when a server it heard goes
silent for ``silence_s`` it publishes ``"stop"`` to every legacy command topic that server named. Its own
Last Will is ``"stop"`` too. It keeps no other state and needs no database: ``fleet-server legacy-sentinel``.

paho runs in its own network thread here; the silence check runs in a second thread and only reads a dict
guarded by a lock.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from backend.comms.client_id import sentinel_client_id
from backend.comms.mqtt_bridge import parse_mqtt_url
from fleet_protocol import (
    HEARTBEAT_SILENCE_S,
    LEGACY_COMMAND_TOPIC,
    LEGACY_STOP,
    QOS_LEGACY_STOP,
    ProtocolError,
    Topics,
    decode_heartbeat,
)

log = logging.getLogger(__name__)

#: how often the silence check runs (its share of the stop latency)
CHECK_PERIOD_S = 0.05


@dataclass
class _Server:
    last_heard: float
    topics: set[str] = field(default_factory=lambda: {LEGACY_COMMAND_TOPIC})
    silent: bool = False


class LegacySentinel:
    def __init__(
        self,
        *,
        mqtt_url: str,
        topics: Topics,
        credentials: tuple[str, str] | None = None,
        silence_s: float = HEARTBEAT_SILENCE_S,
        client_id: str = "",
    ) -> None:
        self._addr = parse_mqtt_url(mqtt_url)
        self._heartbeat_topic = topics.heartbeat()
        self._silence_s = silence_s
        self._servers: dict[str, _Server] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.stops_sent = 0
        self.rejected = 0
        self._client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=client_id or sentinel_client_id(""))
        self._client.will_set(LEGACY_COMMAND_TOPIC, LEGACY_STOP, qos=QOS_LEGACY_STOP)
        user, password = credentials or (self._addr.username, self._addr.password)
        if user:
            self._client.username_pw_set(user, password)
        if self._addr.tls:
            self._client.tls_set()
        self._client.on_connect = self._on_connect
        self._client.on_message = self._on_message
        self._checker = threading.Thread(target=self._check_loop, name="legacy-sentinel-check", daemon=True)

    # -- paho's thread -----------------------------------------------------------------------------------
    def _on_connect(self, client: mqtt.Client, userdata: object, flags: object, rc: object, props: object) -> None:
        client.subscribe(self._heartbeat_topic, qos=0)  # again on every reconnect
        log.info("legacy sentinel connected, watching %s", self._heartbeat_topic)

    def _on_message(self, client: mqtt.Client, userdata: object, msg: mqtt.MQTTMessage) -> None:
        try:
            beat = decode_heartbeat(bytes(msg.payload))
        except ProtocolError as exc:
            self.rejected += 1
            log.warning("heartbeat rejected (%s)", exc.reason)
            return
        except Exception:  # never let an exception escape into paho's loop
            self.rejected += 1
            log.exception("heartbeat handling failed")
            return
        with self._lock:
            server = self._servers.get(beat.server_id)
            if server is None:
                server = self._servers[beat.server_id] = _Server(last_heard=time.monotonic())
                log.info("server %s heard", beat.server_id)
            elif server.silent:
                log.info("server %s heard again", beat.server_id)
            server.last_heard = time.monotonic()
            server.silent = False
            server.topics.update(t for t in beat.legacy_topics if _is_legacy_command_topic(t))

    # -- the checker thread ------------------------------------------------------------------------------
    def _check_loop(self) -> None:
        while not self._stop.wait(CHECK_PERIOD_S):
            self.check(time.monotonic())

    def check(self, now: float) -> None:
        """Stop the topics of every server silent for longer than ``silence_s`` (once per silence)."""
        due: list[tuple[str, set[str]]] = []
        with self._lock:
            for server_id, server in self._servers.items():
                if not server.silent and now - server.last_heard > self._silence_s:
                    server.silent = True
                    due.append((server_id, set(server.topics)))
        for server_id, topics in due:
            log.warning(
                "server %s silent for %.1f s: stop to %s", server_id, self._silence_s, ", ".join(sorted(topics))
            )
            for topic in sorted(topics):
                self._client.publish(topic, LEGACY_STOP, qos=QOS_LEGACY_STOP)
                self.stops_sent += 1

    # -- lifecycle -----------------------------------------------------------------------------------------
    def start(self) -> None:
        self._client.connect_async(self._addr.host, self._addr.port, keepalive=5)
        self._client.loop_start()
        self._checker.start()

    def stop(self) -> None:
        self._stop.set()
        self._checker.join(timeout=2)
        self._client.disconnect()
        self._client.loop_stop()


def _is_legacy_command_topic(topic: str) -> bool:
    """Only seed command topics: a heartbeat must never make the sentinel publish anywhere else."""
    return topic == LEGACY_COMMAND_TOPIC or (
        topic.endswith("/control/commands") and topic.count("/") == 2 and "+" not in topic and "#" not in topic
    )
