"""A TCP proxy between a client and the broker whose link can be frozen: bytes stop flowing both ways
but the sockets stay open, like a Wi-Fi dropout (nothing tells TCP the peer is gone)."""

from __future__ import annotations

import contextlib
import select
import socket
import threading


class FreezableProxy:
    def __init__(self, target_host: str, target_port: int) -> None:
        self.target = (target_host, target_port)
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(16)
        self.port = int(self.listener.getsockname()[1])
        self.frozen = threading.Event()
        self._forwarding = threading.Lock()
        self._stop = threading.Event()
        self._pairs: list[tuple[socket.socket, socket.socket]] = []
        self._threads = [threading.Thread(target=self._accept, daemon=True, name="proxy-accept")]
        self._threads[0].start()

    @property
    def url(self) -> str:
        return f"mqtt://127.0.0.1:{self.port}"

    def _accept(self) -> None:
        self.listener.settimeout(0.2)
        while not self._stop.is_set():
            try:
                client, _ = self.listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            upstream = socket.create_connection(self.target)
            for s in (client, upstream):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._pairs.append((client, upstream))
            t = threading.Thread(target=self._pump, args=(client, upstream), daemon=True, name="proxy-pump")
            self._threads.append(t)
            t.start()

    def _pump(self, a: socket.socket, b: socket.socket) -> None:
        peers = {a: b, b: a}
        try:
            while not self._stop.is_set():
                if self.frozen.is_set():
                    self._stop.wait(0.01)  # hold everything: neither side hears from the other
                    continue
                ready, _, _ = select.select([a, b], [], [], 0.05)
                # checked again, under the lock freeze() takes: data that came while select waited (a command
                # sent just after freeze() returned) stays in the socket instead of slipping through
                with self._forwarding:
                    if self.frozen.is_set():
                        continue
                    for s in ready:
                        data = s.recv(65536)
                        if not data:
                            return
                        peers[s].sendall(data)
        except OSError:
            return
        finally:
            for s in (a, b):
                with contextlib.suppress(OSError):
                    s.close()

    def freeze(self) -> None:
        """Once this returns, nothing more is forwarded until :meth:`thaw`."""
        with self._forwarding:
            self.frozen.set()

    def thaw(self) -> None:
        self.frozen.clear()

    def close(self) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):
            self.listener.close()
        for t in self._threads:
            t.join(2)
