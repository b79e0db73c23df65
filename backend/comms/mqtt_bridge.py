"""The server's one MQTT client (the only paho importer on the server).

paho runs on the server's asyncio loop, not in a thread of its own: its socket is watched with
``add_reader``/``add_writer`` (paho's external-loop callbacks), ``loop_misc`` runs once a second for
keepalives, and only the blocking TCP/TLS connect runs in the default executor. With a network thread,
every message and every command crossed threads and waited for the GIL (a switch interval is 5 ms): that
wait was most of the command round trip under fleet load. Incoming messages are appended to a bounded
deque and drained to the dispatcher in batches on a later loop turn. Most of them never go through
paho's parser: plain PUBLISH packets (QoS 0/1, no properties) are taken straight from the read buffer
(``_ReadBufferedSocket.take_publishes``, ~1 us each against paho's 29); paho reads everything else.
``publish`` writes at once when called on the loop; ``ack`` may be called from any thread (it is handed
to the loop). No exception ever escapes a paho callback.

Nothing lost: the session is persistent (fixed client id; MQTT v5 ``clean_start=False`` with a session
expiry, or v3.1.1 ``clean_session=False``) and QoS 1 messages are acknowledged by hand: after each drain
the PUBACK tokens go to ``on_ack_marker`` (the writer queues them behind the writes those messages
caused and calls :meth:`MqttBridge.ack` after the commit). A crash before the commit leaves the messages
unacknowledged, so the broker delivers them again. Tokens carry the connection generation: an ack for a
message of an earlier connection is not sent (the broker redelivers that message on the new one).

Roles (MQTT v5 subscription identifiers): ``control`` and ``telemetry`` messages go to the dispatcher;
``store`` (the replicas' shared subscription ``$share/<group>/...``) to ``on_store`` only (stored once
across replicas); ``live`` (every replica's own non-shared telemetry subscription) to the dispatcher,
which then does not store it. A broker without MQTT v5 (e.g. amqtt) makes the bridge fall back to
v3.1.1, where roles cannot be told apart: ``store``/``live`` subscriptions become one ``telemetry``
subscription (single-server behaviour).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any
from urllib.parse import unquote, urlsplit

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion, MQTTErrorCode
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.subscribeoptions import SubscribeOptions

log = logging.getLogger(__name__)

#: Messages handed to the dispatcher per drain; more are left for the next drain so the loop stays responsive.
DRAIN_BATCH = 2000
#: MQTT packets parsed per readable-socket callback; the rest wait one loop turn (HTTP and WebSocket work
#: in between) instead of holding the loop for a whole flood
READ_TURN_PACKETS = 500
#: paho's keepalive/ping bookkeeping runs this often (at most; a quarter of a short keepalive otherwise)
MISC_INTERVAL_S = 1.0
#: reconnect delay after a lost or refused connection: doubles from the first to the last
RECONNECT_DELAY_S = (1.0, 5.0)


#: subscription role -> MQTT v5 subscription identifier
ROLE_IDS: dict[str, int] = {"control": 1, "telemetry": 2, "store": 3, "live": 4}
STORE_ID = ROLE_IDS["store"]

#: an ack token: (connection generation, packet id)
AckToken = tuple[int, int]


@dataclass(slots=True)
class InboundMessage:
    topic: str
    payload: bytes
    retain: bool
    received: float  # server wall clock, epoch seconds
    qos: int = 0
    mid: int = 0
    gen: int = 0
    #: subscription identifiers the broker sent (MQTT v5), empty otherwise
    sub_ids: tuple[int, ...] = ()


@dataclass(frozen=True, slots=True)
class Subscription:
    topic: str
    qos: int
    role: str = "control"  # control | telemetry | store | live


def redact_url(url: str) -> str:
    """``mqtt://user:***@host:port`` (the password never goes to a log)."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    netloc = f"{parts.username}:***@{parts.hostname}" + (f":{parts.port}" if parts.port else "")
    return parts._replace(netloc=netloc).geturl()


def default_client_id() -> str:
    """Stable across restarts of this host's server, so the broker keeps its session."""
    host = "".join(c if c.isalnum() or c in "-_" else "-" for c in socket.gethostname())[:40] or "host"
    return f"fleet-server-{host}"


@dataclass(frozen=True, slots=True)
class BrokerAddress:
    host: str
    port: int
    tls: bool
    username: str | None
    password: str | None


def parse_mqtt_url(url: str) -> BrokerAddress:
    parts = urlsplit(url)
    if parts.scheme not in ("mqtt", "mqtts", "tcp", "ssl"):
        raise ValueError(f"unsupported MQTT URL scheme in {url!r} (use mqtt:// or mqtts://)")
    tls = parts.scheme in ("mqtts", "ssl")
    return BrokerAddress(
        host=parts.hostname or "127.0.0.1",
        port=parts.port or (8883 if tls else 1883),
        tls=tls,
        username=unquote(parts.username) if parts.username else None,
        password=unquote(parts.password) if parts.password else None,
    )


class MqttBridge:
    def __init__(
        self,
        url: str,
        subscriptions: Sequence[tuple[str, int] | tuple[str, int, str] | Subscription],
        on_messages: Callable[[list[InboundMessage]], None],
        on_connection_change: Callable[[bool], None] | None = None,
        client_id: str = "",
        keepalive: int = 10,
        queue_max: int = 200_000,
        protocol: str = "5",
        session_expiry_s: int = 86400,
        receive_maximum: int = 2000,
        on_store: Callable[[list[InboundMessage]], None] | None = None,
        on_ack_marker: Callable[[list[AckToken]], Any] | None = None,
        credentials: tuple[str, str] | None = None,
    ) -> None:
        self.url = url
        #: for logs: never the password
        self.url_redacted = redact_url(url)
        self._addr = parse_mqtt_url(url)
        if credentials is not None:
            self._addr = replace(self._addr, username=credentials[0], password=credentials[1])
        self._subscriptions = [s if isinstance(s, Subscription) else Subscription(*s) for s in subscriptions]
        self._on_messages = on_messages
        self._on_store = on_store
        self._on_connection_change = on_connection_change
        #: called after every drain with its QoS 1 ack tokens (possibly none) - the owner queues them behind
        #: the drain's writes (TelemetryIngest.drained); None: ack right after the dispatch
        self.on_ack_marker = on_ack_marker
        self._keepalive = keepalive
        self._inbox: deque[InboundMessage] = deque()
        self._queue_max = queue_max
        self._drain_scheduled = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread = 0
        self._connected = threading.Event()
        self._stopping = False
        self._keeper: asyncio.Task[None] | None = None
        #: the connect running in the executor (stop waits for it before closing the socket)
        self._connecting: asyncio.Future[Any] | None = None
        #: fd of the socket registered with the loop, and set when paho closes it
        self._sock_fd = -1
        self._sock_closed: asyncio.Event | None = None
        self._reconnect_delay = RECONNECT_DELAY_S[0]
        self.connect_failures = 0
        self._gen = 0
        self.v5 = protocol == "5"
        self.client_id = client_id or default_client_id()
        self.session_present = False
        self.received = 0
        self.dropped = 0
        self.callback_errors = 0
        self.acks_sent = 0
        self.acks_stale = 0
        self._client = _ChunkReadingClient(
            CallbackAPIVersion.VERSION2,
            client_id=self.client_id,
            protocol=mqtt.MQTTv5 if self.v5 else mqtt.MQTTv311,
            clean_session=None if self.v5 else False,
        )
        self._client.manual_ack_set(True)
        self._connect_properties: Properties | None = None
        if self.v5:
            props = Properties(PacketTypes.CONNECT)
            props.SessionExpiryInterval = session_expiry_s
            props.ReceiveMaximum = receive_maximum
            self._connect_properties = props
        # (MQTT 3.1.1 has no receive maximum: the broker's max_inflight_messages applies)
        if self._addr.username:
            self._client.username_pw_set(self._addr.username, self._addr.password)
        if self._addr.tls:
            self._client.tls_set()
        self._client.on_connect = self._on_connect
        self._client.on_disconnect = self._on_disconnect
        self._client.on_socket_open = self._on_socket_open
        self._client.on_socket_close = self._on_socket_close
        self._client.on_socket_register_write = self._on_socket_register_write
        self._client.on_socket_unregister_write = self._on_socket_unregister_write
        self._client.on_message = self._on_message
        self._client.fast_publish = self._on_fast_publish

    @property
    def subscriptions(self) -> list[Subscription]:
        """What is subscribed on (re)connect; on v3.1.1 store/live collapse into one telemetry filter."""
        if self.v5:
            return list(self._subscriptions)
        out = [s for s in self._subscriptions if s.role not in ("store", "live")]
        live = [s for s in self._subscriptions if s.role == "live"]
        for s in live:
            out.append(Subscription(s.topic, 1, "telemetry"))
        return out

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """Connect in the background (call on ``loop``): the server starts, and reports degraded, while the
        broker is down."""
        self._loop = loop
        self._loop_thread = threading.get_ident()
        self._sock_closed = asyncio.Event()
        if self.v5:
            self._client.connect_async(
                self._addr.host,
                self._addr.port,
                keepalive=self._keepalive,
                clean_start=False,
                properties=self._connect_properties,
            )
        else:
            self._client.connect_async(self._addr.host, self._addr.port, keepalive=self._keepalive)
        self._keeper = loop.create_task(self._keep_connected(), name="mqtt-bridge")

    async def stop(self) -> None:
        """Send DISCONNECT (the session stays on the broker) and close the socket; call on the loop."""
        self._stopping = True
        connecting = self._connecting
        if self._keeper is not None:
            self._keeper.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._keeper
        if connecting is not None:  # a connect in the executor cannot be cancelled: let it finish
            await asyncio.wait([connecting], timeout=10)
        try:
            self._client.disconnect()
            self._client.loop_write()  # sends DISCONNECT, then paho closes the socket
        finally:
            self._client._sock_close()  # no-op when paho closed it
            self._connected.clear()

    def publish(self, topic: str, payload: bytes | str, qos: int = 1, retain: bool = False) -> bool:
        """Send at once when called on the loop (from another thread, the loop's writer callback sends
        it). QoS>0 messages published while disconnected are queued by paho and sent after reconnecting."""
        info = self._client.publish(topic, payload, qos=qos, retain=retain)
        if info.rc not in (MQTTErrorCode.MQTT_ERR_SUCCESS, MQTTErrorCode.MQTT_ERR_NO_CONN):
            log.warning("publish to %s failed: %s", topic, mqtt.error_string(info.rc))
            return False
        if info.rc == MQTTErrorCode.MQTT_ERR_SUCCESS and threading.get_ident() == self._loop_thread:
            self._write()
        return info.rc == MQTTErrorCode.MQTT_ERR_SUCCESS or qos > 0

    def ack(self, tokens: list[AckToken]) -> None:
        """PUBACK committed messages (thread-safe: the writer thread calls it after its commit)."""
        if threading.get_ident() == self._loop_thread:
            self._ack_now(tokens)
        elif self._loop is not None:
            with contextlib.suppress(RuntimeError):  # loop closed: the broker redelivers them
                self._loop.call_soon_threadsafe(self._ack_now, tokens)

    def _ack_now(self, tokens: list[AckToken]) -> None:
        gen = self._gen
        mids = [mid for token_gen, mid in tokens if token_gen == gen]
        # the rest arrived on an earlier connection: the broker sends those again
        self.acks_stale += len(tokens) - len(mids)
        if mids:
            self._client.puback_many(mids)
            self.acks_sent += len(mids)
            self._write()

    def stats(self) -> dict[str, Any]:
        return {
            "connected": self.connected,
            "client_id": self.client_id,
            "protocol": "5" if self.v5 else "3.1.1",
            "session_present": self.session_present,
            "received": self.received,
            "parsed_without_paho": self._client.fast_taken,
            "inbox": len(self._inbox),
            "dropped": self.dropped,
            "callback_errors": self.callback_errors,
            "acks_sent": self.acks_sent,
            "acks_stale": self.acks_stale,
            "connect_failures": self.connect_failures,
        }

    # -- connection (event loop) -----------------------------------------------------------------------
    async def _keep_connected(self) -> None:
        """Connect, run paho's keepalive bookkeeping while connected, reconnect after a loss (1 s, then
        doubling up to 5 s while connects fail or are refused)."""
        loop = asyncio.get_running_loop()
        closed = self._sock_closed
        assert closed is not None
        while not self._stopping:
            closed.clear()
            self._connecting = loop.run_in_executor(None, self._client.reconnect)
            try:
                await asyncio.shield(self._connecting)  # stop() waits for it: a thread cannot be cancelled
            except Exception as exc:  # refused, unreachable, DNS, TLS: try again later
                self.connect_failures += 1
                n = self.connect_failures
                level = logging.WARNING if n == 1 or n % 60 == 0 else logging.DEBUG
                log.log(level, "MQTT connect to %s failed (%d so far): %s", self.url_redacted, n, exc)
                closed.set()
            finally:
                self._connecting = None
            interval = min(MISC_INTERVAL_S, max(self._keepalive / 4, 0.1))
            while not closed.is_set():
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(closed.wait(), interval)
                if not closed.is_set():
                    self._misc()
            await asyncio.sleep(self._reconnect_delay)
            self._reconnect_delay = min(self._reconnect_delay * 2, RECONNECT_DELAY_S[1])

    def _in_loop(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn`` now when on the loop's thread, else hand it to the loop (connects run elsewhere)."""
        if threading.get_ident() == self._loop_thread:
            fn(*args)
        elif self._loop is not None:
            with contextlib.suppress(RuntimeError):  # loop closed during shutdown
                self._loop.call_soon_threadsafe(fn, *args)

    def _on_socket_open(self, client: mqtt.Client, userdata: object, sock: Any) -> None:
        _no_delay(client, userdata, sock)
        self._in_loop(self._watch_socket, sock, sock.fileno())

    def _watch_socket(self, sock: Any, fd: int) -> None:
        assert self._loop is not None
        if self._client.socket() is not sock:
            return  # already closed again
        self._sock_fd = fd
        self._loop.add_reader(fd, self._on_readable)

    def _on_socket_close(self, client: mqtt.Client, userdata: object, sock: Any) -> None:
        # the fd is read now: paho closes the socket right after this callback
        self._in_loop(self._unwatch_socket, sock.fileno())

    def _unwatch_socket(self, fd: int) -> None:
        assert self._loop is not None
        if fd == self._sock_fd:
            self._loop.remove_reader(fd)
            self._loop.remove_writer(fd)
            self._sock_fd = -1
        if self._sock_closed is not None:
            self._sock_closed.set()

    def _on_socket_register_write(self, client: mqtt.Client, userdata: object, sock: Any) -> None:
        self._in_loop(self._watch_writable, sock)

    def _watch_writable(self, sock: Any) -> None:
        # paho registers once and expects loop_write calls until it unregisters: never skipped
        assert self._loop is not None
        if self._client.socket() is sock and self._sock_fd >= 0:
            self._loop.add_writer(self._sock_fd, self._write)

    def _on_socket_unregister_write(self, client: mqtt.Client, userdata: object, sock: Any) -> None:
        self._in_loop(self._unwatch_writable, sock.fileno())

    def _unwatch_writable(self, fd: int) -> None:
        assert self._loop is not None
        if fd == self._sock_fd:
            self._loop.remove_writer(fd)

    def _on_readable(self) -> None:
        try:
            self._client.loop_read()
            sock: Any = self._client.socket()
            pending = getattr(sock, "pending", None)
            if sock is not None and pending is not None and pending() and self._loop is not None:
                self._loop.call_soon(self._on_readable)  # buffered bytes select() does not see
        except Exception:
            self.callback_errors += 1
            log.exception("error reading from MQTT")

    def _write(self) -> None:
        self._guarded(self._client.loop_write, "writing to MQTT")

    def _misc(self) -> None:
        """PINGREQ when the link is idle; closes the socket when a PINGRESP is overdue."""
        self._guarded(self._client.loop_misc, "in MQTT keepalive")

    def _guarded(self, step: Callable[[], Any], what: str) -> None:
        """Loop callbacks never raise: an error is counted and logged, and the loop goes on."""
        try:
            step()
        except Exception:
            self.callback_errors += 1
            log.exception("error %s", what)

    # -- paho callbacks (event loop) --------------------------------------------------------------------------
    def _on_connect(
        self, client: mqtt.Client, userdata: object, flags: object, reason_code: object, properties: object
    ) -> None:
        try:
            if getattr(reason_code, "is_failure", False):
                if self.v5 and str(reason_code) == "Unsupported protocol version":
                    self._downgrade()
                    return
                log.error("MQTT connect to %s refused: %s", self.url_redacted, reason_code)
                return
            self._gen += 1  # acks for messages of the previous connection must not be sent on this one
            self._reconnect_delay = RECONNECT_DELAY_S[0]
            self.session_present = bool(getattr(flags, "session_present", False))
            # Subscriptions are re-made on every (re)connect (a session that expired forgot them).
            self._subscribe(client)
            self._connected.set()
            log.info(
                "MQTT connected to %s as %s (MQTT %s, session %s), subscribed to %s",
                self.url_redacted,
                self.client_id,
                "5" if self.v5 else "3.1.1",
                "resumed" if self.session_present else "new",
                [f"{s.topic} ({s.role})" for s in self.subscriptions],
            )
            self._notify_connection(True)
        except Exception:
            self.callback_errors += 1
            log.exception("error in MQTT on_connect")

    def _subscribe(self, client: mqtt.Client) -> None:
        subs = self.subscriptions
        if not subs:
            return
        if not self.v5:
            client.subscribe([(s.topic, s.qos) for s in subs])
            return
        if not any(s.role == "store" for s in subs):
            # One server: nothing to tell apart, and without subscription identifiers paho has no
            # properties to parse in each PUBLISH (a tenth of the ingest CPU at 10,000 msg/s).
            client.subscribe([(s.topic, SubscribeOptions(qos=s.qos)) for s in subs])
            return
        for role in sorted({s.role for s in subs}):
            props = Properties(PacketTypes.SUBSCRIBE)
            props.SubscriptionIdentifier = ROLE_IDS.get(role, ROLE_IDS["control"])
            client.subscribe([(s.topic, SubscribeOptions(qos=s.qos)) for s in subs if s.role == role], properties=props)

    def _downgrade(self) -> None:
        """The broker does not speak MQTT v5: go on with v3.1.1 (paho downgrades 3.1.1 to 3.1 the same way)."""
        self.v5 = False
        client: Any = self._client
        client._protocol = mqtt.MQTTv311
        client._clean_session = False
        log.warning(
            "MQTT broker %s does not support MQTT v5: using 3.1.1 (no shared-subscription ingest)",
            self.url_redacted,
        )

    def _on_disconnect(
        self, client: mqtt.Client, userdata: object, flags: object, reason_code: object, properties: object
    ) -> None:
        try:
            was = self._connected.is_set()
            self._connected.clear()
            if was and not self._stopping:
                log.warning("MQTT disconnected from %s: %s", self.url_redacted, reason_code)
                self._notify_connection(False)
        except Exception:
            self.callback_errors += 1
            log.exception("error in MQTT on_disconnect")

    def _notify_connection(self, connected: bool) -> None:
        if self._loop is not None and self._on_connection_change is not None and not self._loop.is_closed():
            self._loop.call_soon_threadsafe(self._on_connection_change, connected)

    def _on_message(self, client: mqtt.Client, userdata: object, msg: mqtt.MQTTMessage) -> None:
        """What paho parsed itself: messages with properties (a replica's subscription identifiers), QoS 2."""
        try:
            sub_ids: tuple[int, ...] = ()
            props = getattr(msg, "properties", None)
            if props is not None:
                ids = getattr(props, "SubscriptionIdentifier", None)
                if ids:
                    sub_ids = tuple(ids) if isinstance(ids, list) else (int(ids),)
            self._accept(msg.topic, bytes(msg.payload), bool(msg.retain), msg.qos, msg.mid, sub_ids)
        except Exception:
            self.callback_errors += 1
            log.exception("error in MQTT on_message")

    def _on_fast_publish(self, topic: str, payload: bytes, retain: bool, qos: int, mid: int) -> None:
        """Plain PUBLISH packets parsed by :class:`_ChunkReadingClient` without paho (most of the traffic)."""
        try:
            self._accept(topic, payload, retain, qos, mid, ())
        except Exception:
            self.callback_errors += 1
            log.exception("error taking an MQTT message")

    def _accept(self, topic: str, payload: bytes, retain: bool, qos: int, mid: int, sub_ids: tuple[int, ...]) -> None:
        self.received += 1
        if qos == 0 and len(self._inbox) >= self._queue_max:
            # QoS 1 is never dropped here: its count is bounded by the receive maximum (unacked)
            self.dropped += 1
            if self.dropped == 1 or self.dropped % 1000 == 0:
                log.warning("MQTT inbox full (%d): %d messages dropped", self._queue_max, self.dropped)
            return
        self._inbox.append(InboundMessage(topic, payload, retain, time.time(), qos, mid, self._gen, sub_ids))
        if not self._drain_scheduled and self._loop is not None:
            self._drain_scheduled = True
            self._loop.call_soon(self._drain)  # once per read: the drain takes the whole batch

    # -- dispatch (event loop) --------------------------------------------------------------------------------
    def _drain(self) -> None:
        self._drain_scheduled = False
        batch: list[InboundMessage] = []
        inbox = self._inbox
        while inbox and len(batch) < DRAIN_BATCH:
            batch.append(inbox.popleft())
        if inbox and self._loop is not None:
            self._drain_scheduled = True
            self._loop.call_soon(self._drain)
        if not batch:
            return
        dispatch: list[InboundMessage] = []
        store: list[InboundMessage] = []
        tokens: list[AckToken] = []
        for m in batch:
            if m.qos:
                tokens.append((m.gen, m.mid))
            if STORE_ID in m.sub_ids and self._on_store is not None:
                store.append(m)
                if len(m.sub_ids) == 1:
                    continue
            dispatch.append(m)
        try:
            if dispatch:
                self._on_messages(dispatch)
            if store and self._on_store is not None:
                self._on_store(store)
        except Exception:
            self.callback_errors += 1
            log.exception("error dispatching %d MQTT messages", len(batch))
        if self.on_ack_marker is not None:
            self.on_ack_marker(tokens)  # acked after the writes these messages caused are committed
        elif tokens:
            self.ack(tokens)


_PUBACK = 0x40
#: PUBACK fixed header with remaining length 2: packet id only (MQTT 3.1.1; in v5 it means "Success")
_PUBACK_HEADER = bytes([_PUBACK, 2])


#: takes (topic, payload, retain, qos, mid) of a PUBLISH parsed without paho
PublishSink = Callable[[str, bytes, bool, int, int], None]


class _ReadBufferedSocket:
    """A plain TCP socket read in 64 KiB chunks. paho 2.x reads every packet with three or more recv()
    calls (command byte, each length byte, body) and a select() in between; at 10,000 msg/s that was about
    a third of the server's CPU. Small reads are served from memory here, and ``pending()`` (what paho
    asks a TLS socket) tells paho to read on without waiting in select(). :meth:`take_publishes` parses
    plain PUBLISH packets straight from the buffer (see :class:`_ChunkReadingClient`)."""

    __slots__ = ("_buf", "_eof", "_error", "_pos", "_sock")

    def __init__(self, sock: socket.socket) -> None:
        self._sock = sock
        self._buf = b""
        self._pos = 0
        self._eof = False
        self._error: OSError | None = None

    def recv(self, bufsize: int) -> bytes:
        avail = len(self._buf) - self._pos
        if avail == 0:
            if self._error is not None:  # met by fill(): paho reports it as it would have
                error, self._error = self._error, None
                raise error
            if self._eof:
                return b""  # the peer closed (seen by fill()): paho sees it now
            data = self._sock.recv(max(bufsize, 65536))  # BlockingIOError when nothing is there
            if len(data) <= bufsize:
                return data  # b"" at EOF
            self._buf, self._pos, avail = data, 0, len(data)
        end = self._pos + min(bufsize, avail)
        out = self._buf[self._pos : end]
        if end == len(self._buf):
            self._buf, self._pos = b"", 0
        else:
            self._pos = end
        return out

    def pending(self) -> int:
        return len(self._buf) - self._pos

    def fill(self) -> bool:
        """Read what the socket has when the buffer is empty; False when there is nothing to read now.
        An error or EOF is kept for paho's next ``recv`` (it reports a lost connection, as it always has)."""
        if self._pos < len(self._buf) or self._eof or self._error is not None:
            return True
        try:
            data = self._sock.recv(65536)
        except BlockingIOError:
            return False
        except OSError as exc:
            self._error = exc
            return True
        if data:
            self._buf, self._pos = data, 0
        else:
            self._eof = True
        return True

    def take_publishes(self, sink: PublishSink, limit: int, v5: bool) -> int:
        """Hand complete QoS 0/1 PUBLISH packets without properties at the head of the buffer to ``sink``;
        stop at anything else (another packet type, QoS 2, v5 properties such as subscription
        identifiers, a topic that is not UTF-8, a packet not all here yet), which paho then reads as
        usual. Returns how many were taken. Call only between packets (paho holds no partial one)."""
        buf, pos, size = self._buf, self._pos, len(self._buf)
        taken = 0
        while taken < limit and pos < size:
            first = buf[pos]
            if first >> 4 != 3 or first & 0x04:
                break  # not a PUBLISH, or QoS 2 (or the invalid 3)
            p, length, shift = pos + 1, 0, 0
            while p < size and shift <= 21:
                byte = buf[p]
                p += 1
                length |= (byte & 0x7F) << shift
                if byte < 0x80:
                    break
                shift += 7
            else:
                break  # remaining length not all here (or malformed: paho says so)
            end = p + length
            if end > size or p + 2 > end:
                break
            topic_end = p + 2 + ((buf[p] << 8) | buf[p + 1])
            qos = (first >> 1) & 0x03
            body = topic_end + (2 if qos else 0)
            if body + (1 if v5 else 0) > end or (v5 and buf[body] != 0):
                break  # truncated, or v5 properties: paho parses those
            try:
                topic = buf[p + 2 : topic_end].decode()
            except UnicodeDecodeError:
                break
            mid = (buf[topic_end] << 8) | buf[topic_end + 1] if qos else 0
            sink(topic, buf[body + 1 if v5 else body : end], bool(first & 0x01), qos, mid)
            pos = end
            taken += 1
        if pos >= size:
            self._buf, self._pos = b"", 0
        else:
            self._pos = pos
        return taken

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sock, name)


class _ChunkReadingClient(mqtt.Client):
    """paho's client over :class:`_ReadBufferedSocket` (plain TCP only; TLS sockets buffer themselves),
    reading every buffered packet per network-loop turn instead of one."""

    def _create_socket(self) -> Any:
        sock = super()._create_socket()
        if type(sock) is socket.socket:
            return _ReadBufferedSocket(sock)
        return sock

    def puback_many(self, mids: list[int]) -> None:
        """PUBACK many QoS 1 messages as one queued write (paho's ``ack`` queues and sends each 4-byte
        PUBACK on its own: a sixth of the ingest CPU)."""
        if mids:
            blob = b"".join([_PUBACK_HEADER + mid.to_bytes(2, "big") for mid in mids])
            self._packet_queue(_PUBACK, blob, 0, 1)

    #: set by the bridge: plain PUBLISH packets go here without paho's per-packet work (29 us of Python
    #: each here, against about 1 us: paho builds an MQTTMessage and a Properties object per message)
    fast_publish: PublishSink | None = None
    #: PUBLISH packets taken by the fast path (the rest went through paho)
    fast_taken = 0

    def loop_read(self, max_packets: int = 1) -> MQTTErrorCode:
        sock: Any = self._sock
        if not isinstance(sock, _ReadBufferedSocket):
            return super().loop_read(max_packets)
        buffered: _ReadBufferedSocket = sock  # (``sock`` is compared with paho's current socket below)
        rc = MQTTErrorCode.MQTT_ERR_SUCCESS
        turns = 0  # bounded, so PUBACKs and pings still go out under a flood
        while self._sock is sock and turns < READ_TURN_PACKETS:
            sink = self.fast_publish
            if sink is not None and self._in_packet["command"] == 0:
                if not buffered.fill():
                    break  # nothing more to read now
                taken = buffered.take_publishes(sink, READ_TURN_PACKETS - turns, self._protocol == mqtt.MQTTv5)
                if taken:
                    self.fast_taken += taken
                    turns += taken
                    with self._msgtime_mutex:
                        self._last_bytes_received = time.monotonic()  # paho's keepalive clock
                    continue
            rc = super().loop_read(max_packets)  # one packet the fast path left (or the socket's news)
            turns += 1
            if rc != MQTTErrorCode.MQTT_ERR_SUCCESS or not buffered.pending():
                break
        return rc


def _no_delay(client: Any, userdata: Any, sock: Any) -> None:
    """Disable Nagle on the broker link: otherwise each command waits for a delayed ACK (~40 ms)."""
    with contextlib.suppress(OSError, AttributeError):  # not a TCP socket
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
