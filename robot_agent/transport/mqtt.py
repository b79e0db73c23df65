"""The agent's MQTT link: the only module of the agent that imports paho.

paho runs its own network thread (``loop_start``). Everything it reports crosses into the agent's asyncio
loop with ``loop.call_soon_threadsafe``; callbacks never raise. All publishing happens on the asyncio loop.

Telemetry ordering across a broker outage (decided deliberately):

* While the link is up and "ready", telemetry is handed straight to paho (QoS 1). paho keeps every QoS 1
  message it has not had a PUBACK for and resends it after a reconnect; those "held-over" messages are the
  oldest ones, tracked here by message id (``_pending``).
* While the link is down (or not yet ready), telemetry goes into our own bounded buffer (``buffer_size``,
  drop-oldest, drops counted and reported in the status as ``buffer_dropped``); paho never sees it.
* On reconnect we publish the online status, then wait until every held-over message is acked (paho resends
  them right after CONNACK), then flush our buffer in order, then mark the link ready again. So the broker
  receives telemetry in seq order without gaps (apart from counted drops). A held-over message that never
  gets acked (the broker lost it) releases the flush after ``held_over_timeout_s``.
* paho's own queue is bounded (``max_queued_messages_set``) and inflight is bounded; a publish refused by a
  full paho queue is counted as dropped.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import socket
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion, MQTTErrorCode

from fleet_protocol import (
    QOS_ACK,
    QOS_CAMERA,
    QOS_COMMAND,
    QOS_CONFIG,
    QOS_ESTOP,
    QOS_PING,
    QOS_REPAIR,
    QOS_STATUS,
    QOS_TELEMETRY,
    QOS_TIME,
    Topics,
)

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
        self._on_command = on_command
        self._on_estop = on_estop
        self._on_link = on_link
        self._on_ping = on_ping
        self._on_time = on_time
        self._on_repair = on_repair
        #: Further topics to hear (the server's heartbeat, the site): topic -> (QoS, handler on the loop).
        self._subscriptions = dict(subscriptions or {})
        self.buffer_size = buffer_size
        self.held_over_timeout_s = held_over_timeout_s
        self.stats = TransportStats()
        #: monotonic time of the last message the server will see (status, telemetry, ack, camera)
        self.last_publish = 0.0

        self._status_topic = topics.status(robot_id)
        self._cmd_topic = topics.cmd(robot_id)
        self._estop_topic = topics.estop()
        self._ack_topic = topics.ack(robot_id)
        self._ping_topic = topics.ping(robot_id)
        self._time_req_topic = topics.time_req(robot_id)
        self._time_resp_topic = topics.time_resp(robot_id)
        self._repair_request_topic = topics.repair_request(robot_id)
        self._repair_reply_topic = topics.repair_reply(robot_id)
        self._config_topic = topics.config(robot_id)

        # Loop-thread state.
        self._buffer: collections.deque[tuple[str, bytes, bool]] = collections.deque()
        self._ready = False
        self._pending: set[int] = set()  # telemetry mids handed to paho, not yet PUBACKed
        self._early: dict[int, float] = {}  # PUBACKs seen before we recorded the mid
        self._flush_started: float | None = None
        self._flush_handle: asyncio.TimerHandle | None = None
        self._dropped_reported = 0  # buffer_dropped as of the last status published
        # Written by the paho thread, read by the loop (plain attribute reads/writes are atomic).
        self._acked: collections.deque[int] = collections.deque()
        self._paho_connected = False
        self._conn_id = 0
        self._closing = False

        self.client = mqtt.Client(
            CallbackAPIVersion.VERSION2,
            client_id=f"fleet-agent-{robot_id}-{uuid.uuid4().hex[:6]}",
            clean_session=True,
            reconnect_on_failure=True,
        )
        paho_log = logging.getLogger("robot_agent.paho")
        paho_log.addFilter(self._quiet_when_closing)
        self.client.enable_logger(paho_log)
        if username is not None:
            self.client.username_pw_set(username, password)
        if tls:
            # Verifies the broker's certificate and host name (against tls_ca, or the system's CAs).
            self.client.tls_set(ca_certs=tls_ca)
        self.client.will_set(self._status_topic, will_payload, qos=QOS_STATUS, retain=True)
        self.client.reconnect_delay_set(min_delay=reconnect_min_s, max_delay=reconnect_max_s)  # type: ignore[arg-type]
        self.client.max_inflight_messages_set(max_inflight)
        self.client.max_queued_messages_set(buffer_size + 1000)
        self.client.on_connect = self._cb_connect
        self.client.on_socket_open = _no_delay
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
        if len(self._buffer) >= self.buffer_size:
            self._buffer.popleft()
            self.stats.buffer_dropped += 1
        self._buffer.append((topic, payload, retain))
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
        self._drain_acks()
        if self._early.pop(info.mid, None) is None:
            self._pending.add(info.mid)

    def _drain_acks(self) -> None:
        now = time.monotonic()
        while self._acked:
            mid = self._acked.popleft()
            if mid in self._pending:
                self._pending.discard(mid)
            else:
                self._early[mid] = now
        if len(self._early) > 64:  # acks of untracked publishes: only microseconds-old entries matter
            self._early = {m: t for m, t in self._early.items() if now - t < 5.0}

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
        self._drain_acks()
        started = self._flush_started or time.monotonic()
        if self._pending and time.monotonic() - started < self.held_over_timeout_s:
            # paho is still resending held-over telemetry: flush after those (re-checked on each PUBACK).
            self._flush_handle = self._loop.call_later(0.2, self._try_flush, conn_id)
            return
        if self._pending:
            self.stats.held_over_timeouts += 1
            log.warning("%d held-over telemetry messages were never acked; flushing anyway", len(self._pending))
            self._pending.clear()
        n = len(self._buffer)
        while self._buffer:
            topic, payload, retain = self._buffer.popleft()
            self._hand_telemetry(topic, payload, retain)
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
            subscriptions = [
                (self._cmd_topic, QOS_COMMAND),
                (self._estop_topic, QOS_ESTOP),
                (self._ping_topic, QOS_PING),
                (self._time_resp_topic, QOS_TIME),
                *((topic, qos) for topic, (qos, _) in self._subscriptions.items()),
            ]
            if self._on_repair is not None:
                subscriptions.append((self._repair_request_topic, QOS_REPAIR))
            client.subscribe(subscriptions)
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
            payload = bytes(msg.payload)
            if msg.topic == self._cmd_topic:
                self._post(self._on_command, payload)
            elif msg.topic == self._estop_topic:
                self._post(self._on_estop, payload)
            elif msg.topic == self._ping_topic and self._on_ping is not None:
                self._post(self._on_ping, payload)
            elif msg.topic == self._time_resp_topic and self._on_time is not None:
                self._post(self._on_time, payload, time.monotonic())  # t3: read here, not after the loop's queue
            elif msg.topic == self._repair_request_topic and self._on_repair is not None:
                self._post(self._on_repair, payload)
            elif msg.topic in self._subscriptions:
                self._post(self._subscriptions[msg.topic][1], payload)
        except Exception:
            self.stats.callback_errors += 1
            log.exception("on_message failed")

    def _cb_publish(self, client: mqtt.Client, userdata: Any, mid: int, reason_code: Any, props: Any) -> None:
        # Called with paho's message lock held: only record the id, never take locks here.
        try:
            self._acked.append(mid)
            if not self._ready and self._paho_connected:
                self._post(self._try_flush, self._conn_id)
        except Exception:
            self.stats.callback_errors += 1


def _no_delay(client: Any, userdata: Any, sock: Any) -> None:
    """Disable Nagle: with it, a small ack written right after paho's PUBACK waits for the peer's delayed
    ACK (~40 ms per hop on Linux). Measured: command -> ack round trip 74 ms -> 1 ms on loopback."""
    with contextlib.suppress(OSError, AttributeError):  # not a TCP socket (e.g. unix or websocket)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
