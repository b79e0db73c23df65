"""A lean HTTP/1.1 client for timing the server: one keep-alive socket, requests written as bytes.

httpx spends about 1-1.5 ms of Python per request on this machine building the request and parsing the
response (measured against this client on the same server, no load: p50 5.7 against 4.2 ms with 50 ms
pauses). That is the script's own cost, not the server's or the robot's, so the command bench times both
clients side by side: this one for the system's round trip, httpx for what a researcher's script sees.
"""

from __future__ import annotations

import socket


class RawHttpClient:
    """``post_json`` on one persistent connection (reconnects if the server closed it)."""

    def __init__(self, host: str, port: int, headers: dict[str, str], timeout: float = 10.0) -> None:
        self.host, self.port, self.timeout = host, port, timeout
        self._head = "".join(f"{k}: {v}\r\n" for k, v in headers.items() if k.lower() not in ("host", "content-length"))
        self._sock: socket.socket | None = None

    def _connect(self) -> socket.socket:
        sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock
        return sock

    def post_json(self, path: str, body: bytes) -> tuple[int, bytes]:
        """(status code, response body). The request is one write; the body is read to Content-Length."""
        sock = self._sock or self._connect()
        request = (
            f"POST {path} HTTP/1.1\r\nHost: {self.host}:{self.port}\r\n{self._head}"
            f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n\r\n"
        ).encode() + body
        sock.sendall(request)
        buf = b""
        while b"\r\n\r\n" not in buf:
            chunk = sock.recv(65536)
            if not chunk:
                self.close()
                raise ConnectionError("server closed the connection")
            buf += chunk
        head, _, rest = buf.partition(b"\r\n\r\n")
        lines = head.split(b"\r\n")
        status = int(lines[0].split(b" ", 2)[1])
        length, close = 0, False
        for line in lines[1:]:
            name, _, value = line.partition(b":")
            name = name.strip().lower()
            if name == b"content-length":
                length = int(value)
            elif name == b"connection" and value.strip().lower() == b"close":
                close = True
        while len(rest) < length:
            chunk = sock.recv(65536)
            if not chunk:
                self.close()
                raise ConnectionError("server closed the connection mid-body")
            rest += chunk
        if close:
            self.close()
        return status, rest[:length]

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def open_unread(host: str, port: int, path: str, headers: dict[str, str], rcvbuf: int = 4096) -> socket.socket:
    """Send a GET and then read nothing: a client on a weak link that stopped reading. Its small receive
    buffer makes the server's sends block as soon as its own buffers are full."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.connect((host, port))
    head = "".join(f"{k}: {v}\r\n" for k, v in headers.items() if k.lower() != "host")
    sock.sendall(f"GET {path} HTTP/1.1\r\nHost: {host}:{port}\r\n{head}\r\n".encode())
    return sock


def response_status(sock: socket.socket, timeout: float = 30.0) -> tuple[int, bytes]:
    """The status code of the response on ``sock`` and the bytes read with its head (a few KB at most)."""
    sock.settimeout(timeout)
    buf = b""
    while b"\r\n\r\n" not in buf:
        chunk = sock.recv(4096)
        if not chunk:
            raise ConnectionError("server closed the connection before answering")
        buf += chunk
    return int(buf.split(b" ", 2)[1]), buf


def read_to_end(sock: socket.socket, timeout: float = 30.0) -> bytes:
    """Everything left on ``sock`` until the server closes it."""
    sock.settimeout(timeout)
    parts = []
    while chunk := sock.recv(1 << 20):
        parts.append(chunk)
    return b"".join(parts)
