"""The server's MQTT client id: its public name plus a secret suffix kept in the server's data directory.

Mosquitto lets any account that connects with a client id take it over: the connection already using it is
closed ("already connected, closing old connection"), whatever account it belongs to, and the shipped
Mosquitto cannot bind a client id to an account (``use_username_as_clientid`` would give every replica and
the legacy sentinel the one id of the shared ``fleet-server`` account). A robot account could keep the
server off the broker by reconnecting with its id. So the id carries 128 random bits nobody else knows:
created once, kept in ``<data dir>/mqtt-client-id.secret`` (mode 0600) so every restart of this server
resumes the same persistent session. The name alone (``FLEET_MQTT_CLIENT_ID``, else ``fleet-server-<host>``)
is what the heartbeat, missions and /api/stats show; the suffix never leaves the file and the CONNECT.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
from pathlib import Path

SUFFIX_FILE = "mqtt-client-id.secret"
_SUFFIX = re.compile(r"^[0-9a-f]{32}$")


def secret_suffix(data_dir: Path) -> str:
    """The suffix stored in ``data_dir`` (created on first use); a damaged file is an error, not replaced:
    a new suffix would silently abandon the broker's queued session."""
    data_dir.mkdir(parents=True, exist_ok=True)
    path = data_dir / SUFFIX_FILE
    if not path.exists():
        # written whole under a temporary name, then linked in: a replica starting beside this one (same data
        # directory) reads either no file or the whole suffix, and of two first starts exactly one link wins
        tmp = data_dir / f".{SUFFIX_FILE}.{os.getpid()}.{secrets.token_hex(4)}"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        try:
            with os.fdopen(fd, "w") as f:
                f.write(secrets.token_hex(16) + "\n")
                f.flush()
                os.fsync(f.fileno())
            with contextlib.suppress(FileExistsError):
                os.link(tmp, path)
        finally:
            tmp.unlink()
    suffix = path.read_text().strip()
    if not _SUFFIX.match(suffix):
        raise ValueError(f"{path} does not hold a client id suffix (32 hex digits); remove it to make a new one")
    return suffix


def server_client_id(name: str, data_dir: Path) -> str:
    """``<name>-<secret suffix>``: the id this server's MQTT session lives under."""
    return f"{name}-{secret_suffix(data_dir)}"


def sentinel_client_id(name: str) -> str:
    """The legacy sentinel keeps no session (clean start), so a fresh random suffix on every start will do."""
    return f"{name or 'legacy-sentinel'}-{secrets.token_hex(16)}"
