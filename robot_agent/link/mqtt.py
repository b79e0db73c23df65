"""The agent's MQTT link: the connection, what the robot publishes, and the link's state. With
:mod:`.paho_client` (the client's set-up) and :mod:`.oneshot`, the only agent code that imports paho.

paho runs its own network thread (``loop_start``). Everything it reports crosses into the agent's asyncio
loop with ``loop.call_soon_threadsafe``; callbacks never raise. All publishing happens on the asyncio loop.
What the robot subscribes to, and which handler hears each message: :mod:`.inbound`.

Telemetry keeps its seq order across a broker outage: the offline buffer (``buffer_size``, drop-oldest) and
the held-over messages paho resends after a reconnect are :class:`~.outbox.TelemetryOutbox`'s, whose
docstring gives the rules; a held-over message never acked releases the flush after ``held_over_timeout_s``.
paho's own queue is bounded and inflight is bounded; a publish refused by a full paho queue counts as dropped.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import MQTTErrorCode

from fleet_protocol import (
    QOS_ACK,
    QOS_CAMERA,
    QOS_CONFIG,
    QOS_PING,
    QOS_REPAIR,
    QOS_STATUS,
    QOS_TELEMETRY,
    QOS_TIME,
    Topics,
)
from robot_agent.link.inbound import Inbound
from robot_agent.link.outbox import TelemetryOutbox
from robot_agent.link.paho_client import new_client

log = logging.getLogger(__name__)

_OK_RC = (MQTTErrorCode.MQTT_ERR_SUCCESS, MQTTErrorCode.MQTT_ERR_NO_CONN)


@dataclass
class TransportStats:
    connects: int = 0
    disconnects: int = 0
    buffered: int = 0
    buffer_dropped: int = 0
    paho_queue_full: int = 0
    flushed: int = 0
    callback_errors: int = 0
    held_over_timeouts: int = 0


class MqttTransport:
    """One robot's connection. Construct and use on the asyncio loop; :meth:`start` begins connecting."""

    def __init__(
        self,
        *,
        loop: asyncio.AbstractEventLoop,
        topics: Topics,
        robot_id: str,
        host: str,
        port: int,
        keepalive: int,
        will_payload: bytes,
        status_payload: Callable[[], bytes],
        on_command: Callable[[bytes], None],
        on_estop: Callable[[bytes], None],
        on_link: Callable[[bool], None],
        on_ping: Callable[[bytes], None] | None = None,
        on_time: Callable[[bytes, float], None] | None = None,
        on_repair: Callable[[bytes], None] | None = None,
        subscriptions: dict[str, tuple[int, Callable[[bytes], None]]] | None = None,
        buffer_size: int = 1000,
        reconnect_min_s: float = 0.5,
        reconnect_max_s: float = 10.0,
        max_inflight: int = 100,
        held_over_timeout_s: float = 10.0,
        username: str | None = None,
        password: str | None = None,
        tls: bool = False,
        tls_ca: str | None = None,
        config_payload: bytes | None = None,
    ) -> None:
        self._loop = loop
        self.topics = topics
        self.robot_id = robot_id
        self.host = host
        self.port = port
        self.keepalive = keepalive
        self._status_payload = status_payload
        #: the agent's effective configuration (fleet_protocol.AgentConfig), published retained at every
        #: connect (a restarted broker without persistence forgot it)
        self._config_payload = config_payload
        self._on_link = on_link
        self._inbound = Inbound(
            topics,
            robot_id,
            on_command=on_command,
            on_estop=on_estop,
            on_ping=on_ping,
            on_time=on_time,
            on_repair=on_repair,
            subscriptions=subscriptions,
        )
        self.held_over_timeout_s = held_over_timeout_s
        self.stats = TransportStats()
        #: monotonic time of the last message the server will see (status, telemetry, ack, camera)
        self.last_publish = 0.0

        self._status_topic = topics.status(robot_id)
        self._ack_topic = topics.ack(robot_id)
        self._ping_topic = topics.ping(robot_id)
        self._time_req_topic = topics.time_req(robot_id)
        self._repair_reply_topic = topics.repair_reply(robot_id)
        self._config_topic = topics.config(robot_id)

        # Loop-thread state.
        self._outbox = TelemetryOutbox(buffer_size)
        self._ready = False
        self._flush_started: float | None = None
        self._flush_handle: asyncio.TimerHandle | None = None
        self._dropped_reported = 0  # buffer_dropped as of the last status published
        # Written by the paho thread, read by the loop (plain attribute reads/writes are atomic).
        self._paho_connected = False
        self._conn_id = 0
        self._closing = False

        paho_log = logging.getLogger("robot_agent.paho")
        paho_log.addFilter(self._quiet_when_closing)
        self.client = new_client(
            client_id=f"fleet-agent-{robot_id}-{uuid.uuid4().hex[:6]}",
            will_topic=self._status_topic,
            will_payload=will_payload,
            reconnect_min_s=reconnect_min_s,
            reconnect_max_s=reconnect_max_s,
            max_inflight=max_inflight,
            max_queued=buffer_size + 1000,
            logger=paho_log,
            username=username,
            password=password,
            tls=tls,
            tls_ca=tls_ca,
        )
        self.client.on_connect = self._cb_connect
        self.client.on_disconnect = self._cb_disconnect
        self.client.on_message = self._cb_message
        self.client.on_publish = self._cb_publish

    def _quiet_when_closing(self, record: logging.LogRecord) -> bool:
        """paho logs a harmless "not connected" error when its thread notices our disconnect."""
        return not (self._closing and "not connected" in record.getMessage())

    # ------------------------------------------------------------------------------------------------
    # lifecycle
    def start(self) -> None:
        self.client.connect_async(self.host, self.port, keepalive=self.keepalive)
        self.client.loop_start()

    @property
    def connected(self) -> bool:
        return self._paho_connected

    @property
    def ready(self) -> bool:
        return self._ready

    async def close(self, final_status: bytes | None, timeout: float = 3.0) -> None:
        """Publish ``final_status`` (retained) if connected, disconnect cleanly and join the paho thread."""
        self._closing = True
        if self._flush_handle is not None:
            self._flush_handle.cancel()
        if final_status is not None and self._paho_connected:
            info = self.client.publish(self._status_topic, final_status, qos=QOS_STATUS, retain=True)
            deadline = time.monotonic() + timeout
            while not info.is_published() and self._paho_connected and time.monotonic() < deadline:
                await asyncio.sleep(0.01)
        self.client.disconnect()
        await asyncio.to_thread(self.client.loop_stop)

    # ------------------------------------------------------------------------------------------------
    # publishing (asyncio loop only)
    def publish_telemetry(self, topic: str, payload: bytes, retain: bool = False) -> None:
        if self._ready and self._paho_connected:
            self._hand_telemetry(topic, payload, retain)
            return
        if self._outbox.hold((topic, payload, retain)):
            self.stats.buffer_dropped += 1
        self.stats.buffered += 1

    def publish_ack(self, payload: bytes) -> None:
        """Acks go to paho even while disconnected: paho resends queued QoS 1 messages on reconnect."""
        self._publish_untracked(self._ack_topic, payload, QOS_ACK, False)

    def publish_status(self) -> None:
        if self._paho_connected:
            self._dropped_reported = self.stats.buffer_dropped
            self._publish_untracked(self._status_topic, self._status_payload(), QOS_STATUS, True)

    def publish_ping(self, payload: bytes) -> None:
        """Link probe (QoS 0, never buffered): only meaningful while connected."""
        if self._paho_connected:
            self.client.publish(self._ping_topic, payload, qos=QOS_PING)

    def publish_time_request(self, payload: bytes) -> None:
        """Clock sync (QoS 0, never buffered: a late sample is useless)."""
        if self._paho_connected:
            self.client.publish(self._time_req_topic, payload, qos=QOS_TIME)

    def publish_camera(self, topic: str, payload: bytes) -> None:
        """Camera frames are QoS 0 and live: dropped (not buffered) while the link is down."""
        if self._ready and self._paho_connected:
            self._publish_untracked(topic, payload, QOS_CAMERA, False)

    def publish_repair_reply(self, payload: bytes) -> None:
        """Gap repair replies (QoS 1) go to paho like acks: queued by paho while the link is down."""
        self._publish_untracked(self._repair_reply_topic, payload, QOS_REPAIR, False)

    def _publish_untracked(self, topic: str, payload: bytes, qos: int, retain: bool) -> None:
        self.last_publish = time.monotonic()
        info = self.client.publish(topic, payload, qos=qos, retain=retain)
        if info.rc == MQTTErrorCode.MQTT_ERR_QUEUE_SIZE:
            self.stats.paho_queue_full += 1
            log.warning("paho queue full: message on %s dropped", topic)

    def _hand_telemetry(self, topic: str, payload: bytes, retain: bool) -> None:
        self.last_publish = time.monotonic()
        info = self.client.publish(topic, payload, qos=QOS_TELEMETRY, retain=retain)
        if info.rc not in _OK_RC:
            self.stats.paho_queue_full += 1
            self.stats.buffer_dropped += 1
            return
        self._outbox.handed(info.mid)

    # ------------------------------------------------------------------------------------------------
    # link state (asyncio loop)
    def _link_up(self, conn_id: int) -> None:
        if conn_id != self._conn_id or not self._paho_connected or self._closing:
            return
        self.stats.connects += 1
        log.info("connected to broker %s:%d", self.host, self.port)
        self.publish_status()
        if self._config_payload is not None:
            self._publish_untracked(self._config_topic, self._config_payload, QOS_CONFIG, True)
        self._flush_started = time.monotonic()
        self._try_flush(conn_id)
        self._safe(self._on_link, True)

    def _try_flush(self, conn_id: int) -> None:
        if self._flush_handle is not None:
            self._flush_handle.cancel()
            self._flush_handle = None
        if conn_id != self._conn_id or not self._paho_connected or self._ready or self._closing:
            return
        held_over = self._outbox.held_over()
        started = self._flush_started or time.monotonic()
        if held_over and time.monotonic() - started < self.held_over_timeout_s:
            # paho is still resending held-over telemetry: flush after those (re-checked on each PUBACK).
            self._flush_handle = self._loop.call_later(0.2, self._try_flush, conn_id)
            return
        if held_over:
            self.stats.held_over_timeouts += 1
            log.warning("%d held-over telemetry messages were never acked; flushing anyway", held_over)
            self._outbox.forget_held_over()
        buffered = self._outbox.take()
        for topic, payload, retain in buffered:
            self._hand_telemetry(topic, payload, retain)
        n = len(buffered)
        self.stats.flushed += n
        self._ready = True
        if n:
            log.info("flushed %d buffered telemetry messages", n)
        if self.stats.buffer_dropped != self._dropped_reported:
            # The status sent at connect may predate drops made while held-over messages were being resent:
            # refresh it so ``buffer_dropped`` is exact as soon as the buffer is delivered.
            self.publish_status()

    def _link_down(self, conn_id: int) -> None:
        self._ready = False
        if self._closing:
            return
        self._safe(self._on_link, False)

    def _safe(self, fn: Callable[..., Any], *args: Any) -> None:
        try:
            fn(*args)
        except Exception:
            self.stats.callback_errors += 1
            log.exception("link callback failed")

    # ------------------------------------------------------------------------------------------------
    # paho callbacks (paho thread): never raise, never block, cross with call_soon_threadsafe
    def _post(self, fn: Callable[..., Any], *args: Any) -> None:
        with contextlib.suppress(RuntimeError):  # loop closed during shutdown
            self._loop.call_soon_threadsafe(fn, *args)

    def _cb_connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason_code: Any, props: Any) -> None:
        try:
            if getattr(reason_code, "is_failure", False):
                # "Not authorized" / "Bad user name or password": check username/password in the agent
                # config against `fleet-server robots add`. paho keeps retrying with backoff.
                log.warning("broker refused connection: %s", reason_code)
                return
            client.subscribe(self._inbound.subscriptions())
            self._conn_id += 1
            self._paho_connected = True
            self._post(self._link_up, self._conn_id)
        except Exception:
            self.stats.callback_errors += 1
            log.exception("on_connect failed")

    def _cb_disconnect(self, client: mqtt.Client, userdata: Any, flags: Any, reason_code: Any, props: Any) -> None:
        try:
            was = self._paho_connected
            self._paho_connected = False
            self._ready = False
            if was:
                self.stats.disconnects += 1
                if not self._closing:
                    log.warning("lost broker connection (%s); reconnecting", reason_code)
            self._post(self._link_down, self._conn_id)
        except Exception:
            self.stats.callback_errors += 1

    def _cb_message(self, client: mqtt.Client, userdata: Any, msg: mqtt.MQTTMessage) -> None:
        try:
            delivery = self._inbound.route(msg.topic, bytes(msg.payload))
            if delivery is not None:
                self._post(delivery[0], *delivery[1])
        except Exception:
            self.stats.callback_errors += 1
            log.exception("on_message failed")

    def _cb_publish(self, client: mqtt.Client, userdata: Any, mid: int, reason_code: Any, props: Any) -> None:
        # Called with paho's message lock held: only record the id, never take locks here.
        try:
            self._outbox.acked(mid)
            if not self._ready and self._paho_connected:
                self._post(self._try_flush, self._conn_id)
        except Exception:
            self.stats.callback_errors += 1
