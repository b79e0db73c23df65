"""paho's network I/O on the asyncio loop: its socket is watched with ``add_reader``/``add_writer``
through paho's external-loop callbacks (``on_socket_open`` and friends), so no network thread is needed.
Every callback here runs on the loop (or is handed to it) and never raises into it."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import threading
from collections.abc import Callable
from typing import Any

import paho.mqtt.client as mqtt

log = logging.getLogger(__name__)


class PahoOnLoop:
    """The socket side of :class:`backend.comms.mqtt_bridge.MqttBridge` (a base class of it)."""

    _client: mqtt.Client
    _loop: asyncio.AbstractEventLoop | None
    _loop_thread: int
    #: fd of the socket registered with the loop, and set when paho closes it
    _sock_fd: int
    _sock_closed: asyncio.Event | None
    _callback_errors: int

    def _attach_socket_callbacks(self) -> None:
        self._sock_fd = -1
        self._client.on_socket_open = self._on_socket_open
        self._client.on_socket_close = self._on_socket_close
        self._client.on_socket_register_write = self._on_socket_register_write
        self._client.on_socket_unregister_write = self._on_socket_unregister_write

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
            self._callback_errors += 1
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
            self._callback_errors += 1
            log.exception("error %s", what)


def _no_delay(client: Any, userdata: Any, sock: Any) -> None:
    """Disable Nagle on the broker link: otherwise each command waits for a delayed ACK (~40 ms)."""
    with contextlib.suppress(OSError, AttributeError):  # not a TCP socket
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
