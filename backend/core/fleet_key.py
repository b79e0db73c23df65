"""The fleet key: 32 random bytes the base station and its enrolled robots share, so that a robot follows
only the discovery beacon that proves it holds the key (fleet_protocol/discovery.py, issue 29 #3).

Created once, kept in ``<data dir>/fleet-key.secret`` (64 hex digits, mode 0600): the server makes it at
start, ``POST /api/enrol`` hands it to each robot, and the beacon (``fleet-agent beacon --fleet-key-file``)
reads it. Replicas with data directories of their own need a copy of the same file (docs/security.md).
"""

from __future__ import annotations

import contextlib
import os
import secrets
from pathlib import Path

from fleet_protocol.discovery import FLEET_KEY_BYTES, parse_fleet_key

KEY_FILE = "fleet-key.secret"


def fleet_key_path(data_dir: Path) -> Path:
    return data_dir / KEY_FILE


def fleet_key(data_dir: Path) -> bytes:
    """The key stored in ``data_dir`` (created on first use). A damaged file is an error, never replaced: a
    new key would silently cut every enrolled robot off discovery."""
    data_dir.mkdir(parents=True, exist_ok=True)
    path = fleet_key_path(data_dir)
    if not path.exists():
        # written whole under a temporary name, then linked in: of two first starts exactly one link wins
        tmp = data_dir / f".{KEY_FILE}.{os.getpid()}.{secrets.token_hex(4)}"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        try:
            with os.fdopen(fd, "w") as f:
                f.write(secrets.token_hex(FLEET_KEY_BYTES) + "\n")
                f.flush()
                os.fsync(f.fileno())
            if os.geteuid() == 0:  # a root CLI run: the file belongs to whoever owns the data directory
                owner = data_dir.stat()
                os.chown(tmp, owner.st_uid, owner.st_gid)
            with contextlib.suppress(FileExistsError):
                os.link(tmp, path)
        finally:
            tmp.unlink()
    try:
        return parse_fleet_key(path.read_text())
    except ValueError:
        raise ValueError(f"{path} does not hold a fleet key (64 hex digits); restore it from a backup") from None
