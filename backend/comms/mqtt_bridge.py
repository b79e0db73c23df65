"""The server's one MQTT client (the only paho importer on the server).

paho runs on the server's asyncio loop, not in a thread of its own: its socket is watched with
``add_reader``/``add_writer`` (paho's external-loop callbacks), ``loop_misc`` runs once a second for
keepalives, and only the blocking TCP/TLS connect runs in the default executor. With a network thread,
every message and every command crossed threads and waited for the GIL (a switch interval is 5 ms): that
wait was most of the command round trip under fleet load. Incoming messages are appended to a bounded
deque (``inbox.py``) and drained to the dispatcher in batches on a later loop turn. Most of them never go
through paho's parser: plain PUBLISH packets (QoS 0/1, no properties) are taken straight from the read
buffer (``fast_path.py``, ~1 us each against paho's 29; ``FLEET_MQTT_FAST_PATH``, and only on the paho
release it was tested with); paho reads everything else. The socket plumbing is in ``loop_io.py``.
``publish`` writes at once when called on the loop; ``ack`` may be called from any thread (it is handed
to the loop). No exception ever escapes a paho callback.

Nothing lost: the session is persistent (fixed client id; MQTT v5 ``clean_start=False`` with a session
expiry, or v3.1.1 ``clean_session=False``) and QoS 1 messages are acknowledged by hand: after each drain
the PUBACK tokens go to ``on_ack_marker`` (the writer queues them behind the writes those messages
caused and calls :meth:`MqttBridge.ack` after the commit). A crash before the commit leaves the messages
unacknowledged, so the broker delivers them again. Tokens carry the connection generation: an ack for a
message of an earlier connection is not sent (the broker redelivers that message on the new one). Acks
the writer withholds (what it could not store, :meth:`MqttBridge.withhold`) end in a deliberate reconnect
once the writer has caught up, so the broker delivers those messages again (``redelivery.py``).

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
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion, MQTTErrorCode
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.subscribeoptions import SubscribeOptions

from backend.comms.address import default_client_id, parse_mqtt_url, redact_url
from backend.comms.base import ROLE_IDS, AckToken, InboundMessage, Subscription
from backend.comms.fast_path import ChunkReadingClient, choose_fast_path
from backend.comms.inbox import Inbox
from backend.comms.loop_io import PahoOnLoop
from backend.comms.redelivery import Redelivery
from fleet_common.backoff import Backoff

__all__ = ["AckToken", "InboundMessage", "MqttBridge", "Subscription"]

log = logging.getLogger(__name__)

#: paho's keepalive/ping bookkeeping runs this often (at most; a quarter of a short keepalive otherwise)
MISC_INTERVAL_S = 1.0
#: reconnect delay after a lost or refused connection: doubles from the first to the last
RECONNECT_DELAY_S = (1.0, 5.0)
#: paho's private members the bridge itself touches (the fast path's are in fast_path.py): stop() closes
#: the socket paho may have left open, and a v3.1.1 downgrade rewrites the protocol and session flags
PAHO_BRIDGE_PRIVATE_MEMBERS = ("_sock_close", "_protocol", "_clean_session")


class MqttBridge(PahoOnLoop):
    """The broker link (see the module docstring); implements :class:`backend.comms.base.Communicator`."""

    def __init__(
        self,
        url: str,
        subscriptions: Sequence[tuple[str, int] | tuple[str, int, str] | Subscription],
        on_messages: Callable[[list[InboundMessage]], None],
        on_connection_change: Callable[[bool], None] | None = None,
        client_id: str = "",
        name: str = "",
        keepalive: int = 10,
        queue_max: int = 200_000,
        protocol: str = "5",
        session_expiry_s: int = 86400,
        receive_maximum: int = 2000,
        on_store: Callable[[list[InboundMessage]], None] | None = None,
        on_ack_marker: Callable[[list[AckToken]], Any] | None = None,
        credentials: tuple[str, str] | None = None,
        will: tuple[str, str, int] | None = None,
        fast_path: bool = True,
        redeliver_when: Callable[[], bool] | None = None,
    ) -> None:
        self.url = url
        #: for logs: never the password
        self.url_redacted = redact_url(url)
        self._addr = parse_mqtt_url(url)
        if credentials is not None:
            self._addr = replace(self._addr, username=credentials[0], password=credentials[1])
        self._subscriptions = [s if isinstance(s, Subscription) else Subscription(*s) for s in subscriptions]
        self._on_connection_change = on_connection_change
        self._keepalive = keepalive
        #: ``on_ack_marker`` gets every drain's QoS 1 ack tokens (possibly none): the owner queues them behind
        #: the drain's writes (TelemetryIngest.drained); None: acked right after the dispatch
        self._inbox = Inbox(queue_max, on_messages, on_store, on_ack_marker, self.ack)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread = 0
        self._connected = threading.Event()
        self._stopping = False
        self._keeper: asyncio.Task[None] | None = None
        #: the connect running in the executor (stop waits for it before closing the socket)
        self._connecting: asyncio.Future[Any] | None = None
        self._sock_closed = None
        self._reconnect = Backoff(*RECONNECT_DELAY_S)
        #: withheld acks; ``redeliver_when``: the writer can store what the broker delivers again
        self._redelivery = Redelivery(redeliver_when)
        self.connect_failures = 0
        self._gen = 0
        self.v5 = protocol == "5"
        self.client_id = client_id or default_client_id()
        #: what logs, /api/stats and the heartbeat may show: the id without its secret suffix (comms/client_id.py)
        self.name = name or self.client_id
        self.session_present = False
        self._callback_errors = 0
        self.acks_sent = 0
        self.acks_stale = 0
        self.fast_path, self.fast_path_state = choose_fast_path(fast_path)
        if fast_path and not self.fast_path:
            log.warning("MQTT PUBLISH fast path %s", self.fast_path_state)
        client_class = ChunkReadingClient if self.fast_path else mqtt.Client
        self._client = client_class(
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
        if will is not None:  # sent by the broker when this connection dies without a DISCONNECT
            self._client.will_set(will[0], will[1], qos=will[2])
        if self._addr.username:
            self._client.username_pw_set(self._addr.username, self._addr.password)
        if self._addr.tls:
            self._client.tls_set()
        self._client.on_connect = self._on_connect
        self._client.on_disconnect = self._on_disconnect
        self._attach_socket_callbacks()
        self._client.on_message = self._on_message
        if isinstance(self._client, ChunkReadingClient):
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
    def callback_errors(self) -> int:
        """Errors caught in paho callbacks and in dispatching (never raised into the loop)."""
        return self._callback_errors + self._inbox.errors

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """Connect in the background (call on ``loop``): the server starts, and reports degraded, while the
        broker is down."""
        self._loop = loop
        self._inbox.loop = loop
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
            if isinstance(self._client, ChunkReadingClient):
                self._client.puback_many(mids)
            else:
                for mid in mids:
                    self._client.ack(mid, 1)
            self.acks_sent += len(mids)
            self._write()

    def withhold(self, tokens: list[AckToken]) -> None:
        """Acks never to be sent: their messages were not stored (thread-safe, as :meth:`ack`)."""
        self._in_loop(lambda: self._redelivery.withhold(tokens, self._gen))

    def stats(self) -> dict[str, Any]:
        return {
            "connected": self.connected,
            "client_id": self.name,
            "protocol": "5" if self.v5 else "3.1.1",
            "session_present": self.session_present,
            "received": self._inbox.received,
            "fast_path": self.fast_path_state,
            "parsed_without_paho": getattr(self._client, "fast_taken", 0),
            "inbox": len(self._inbox),
            "dropped": self._inbox.dropped,
            "callback_errors": self.callback_errors,
            "acks_sent": self.acks_sent,
            "acks_stale": self.acks_stale,
            "acks_withheld": self._redelivery.withheld,
            "acks_withheld_now": self._redelivery.withheld_now,
            "redelivery_reconnects": self._redelivery.reconnects,
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
                if not closed.is_set() and self._redelivery.due(time.monotonic()):
                    self._client.disconnect()  # clean: the session stays, no Last Will; then reconnect
                    self._write()
            await asyncio.sleep(0.0 if self._redelivery.take_reconnect() else self._reconnect.next())

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
            self._redelivery.connected()
            self._reconnect.reset()
            self.session_present = bool(getattr(flags, "session_present", False))
            # Subscriptions are re-made on every (re)connect (a session that expired forgot them).
            self._subscribe(client)
            self._connected.set()
            log.info(
                "MQTT connected to %s as %s (MQTT %s, session %s), subscribed to %s",
                self.url_redacted,
                self.name,
                "5" if self.v5 else "3.1.1",
                "resumed" if self.session_present else "new",
                [f"{s.topic} ({s.role})" for s in self.subscriptions],
            )
            self._notify_connection(True)
        except Exception:
            self._callback_errors += 1
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
            self._callback_errors += 1
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
            self._inbox.accept(msg.topic, bytes(msg.payload), bool(msg.retain), msg.qos, msg.mid, self._gen, sub_ids)
        except Exception:
            self._callback_errors += 1
            log.exception("error in MQTT on_message")

    def _on_fast_publish(self, topic: str, payload: bytes, retain: bool, qos: int, mid: int) -> None:
        """Plain PUBLISH packets parsed by :class:`ChunkReadingClient` without paho (most of the traffic)."""
        try:
            self._inbox.accept(topic, payload, retain, qos, mid, self._gen, ())
        except Exception:
            self._callback_errors += 1
            log.exception("error taking an MQTT message")
