"""Mosquitto credentials: password file entries in Mosquitto 2's own format (``$7$``: PBKDF2-SHA512),
written here so no password ever appears on a command line (``mosquitto_passwd -b`` would put it there).

``fleet-server robots add ID`` uses this; ``deploy/mosquitto/`` holds the matching ACL (a robot's username
is its robot id). See docs/security.md.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import os
import secrets
import tempfile
from pathlib import Path

from fleet_protocol import is_valid_robot_id

#: Usernames robots can never have: the server's own broker account (it may read and write everything), the
#: e-stop account (``fleet-agent estop``: writes only the e-stop) and the old-framework robots' shared account
#: (``legacy``: writes every old robot's sensor data; the ACL's deny line keeps it out of fleet/).
RESERVED_USERNAMES = frozenset({"fleet-server", "server", "admin", "root", "fleet-estop", "legacy"})
PBKDF2_ITERATIONS = 1000


def new_broker_password() -> str:
    return secrets.token_urlsafe(24)


def mosquitto_hash(password: str, iterations: int = PBKDF2_ITERATIONS) -> str:
    """``$7$iterations$salt$hash`` exactly as ``mosquitto_passwd`` (Mosquitto >= 2.0) writes it."""
    salt = secrets.token_bytes(12)
    digest = hashlib.pbkdf2_hmac("sha512", password.encode(), salt, iterations)
    return f"$7${iterations}${base64.b64encode(salt).decode()}${base64.b64encode(digest).decode()}"


def verify_mosquitto_hash(password: str, entry: str) -> bool:
    try:
        _, kind, iterations, salt, digest = entry.split("$")
        if kind != "7":
            return False
        expected = base64.b64decode(digest)
        got = hashlib.pbkdf2_hmac("sha512", password.encode(), base64.b64decode(salt), int(iterations))
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(got, expected)


def _check_username(username: str) -> None:
    if not username or any(c in username for c in ":\n\r\0") or len(username) > 64:
        raise ValueError(f"bad broker username {username!r}")


def read_password_file(path: Path) -> dict[str, str]:
    entries: dict[str, str] = {}
    if path.exists():
        for line in path.read_text().splitlines():
            if line.strip() and not line.lstrip().startswith("#") and ":" in line:
                user, _, hashed = line.partition(":")
                entries[user] = hashed
    return entries


def _write_atomically(path: Path, entries: dict[str, str]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    old = path.stat() if path.exists() else None
    mode = old.st_mode & 0o777 if old is not None else 0o600
    fd, tmp = tempfile.mkstemp(prefix=".passwd-", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.writelines(f"{user}:{hashed}\n" for user, hashed in entries.items())
        os.chmod(tmp, mode)
        if old is not None and os.geteuid() == 0:  # run as root: the broker's user keeps its file
            os.chown(tmp, old.st_uid, old.st_gid)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def set_broker_password(path: Path, username: str, password: str) -> None:
    """Add or replace ``username`` in a Mosquitto password file (created 0600 if missing). Mosquitto reads
    the file at start and on SIGHUP."""
    _check_username(username)
    entries = read_password_file(path)
    entries[username] = mosquitto_hash(password)
    _write_atomically(path, entries)


def remove_broker_user(path: Path, username: str) -> bool:
    entries = read_password_file(path)
    if entries.pop(username, None) is None:
        return False
    _write_atomically(path, entries)
    return True


def check_robot_username(robot_id: str) -> None:
    if not is_valid_robot_id(robot_id):
        raise ValueError(f"robot id {robot_id!r} must match [A-Za-z0-9_-]{{1,64}}")
    if robot_id.lower() in RESERVED_USERNAMES:
        raise ValueError(f"{robot_id!r} is reserved for one of the fleet's own broker accounts (acl.example)")


#: Shortest broker password ``broker-init`` accepts from the environment.
MIN_BROKER_PASSWORD_LENGTH = 16


def ensure_broker_password(path: Path, username: str, password: str) -> bool:
    """Set ``username``'s password unless the file already holds exactly it (hashes are salted, so a blind
    rewrite would change the file on every start). Returns True when the file changed."""
    current = read_password_file(path).get(username)
    if current is not None and verify_mosquitto_hash(password, current):
        return False
    set_broker_password(path, username, password)
    return True


def init_broker_auth(
    auth_dir: Path,
    server_username: str,
    server_password: str,
    acl_template: Path,
    sim_robots: list[str] | None = None,
    sim_password: str = "",
) -> list[str]:
    """What the compose ``broker-init`` service does before Mosquitto starts: the server's account (and the
    simulated robots' accounts when their password is set) in ``auth_dir/passwd``, and the shipped ACL as
    ``auth_dir/acl`` unless one is there already (an admin's edits are kept). Entries made by
    ``fleet-server robots add`` are kept. Returns what it did, one line each, never a password."""
    if len(server_password) < MIN_BROKER_PASSWORD_LENGTH:
        raise ValueError(
            f"FLEET_MQTT_PASSWORD must be set (at least {MIN_BROKER_PASSWORD_LENGTH} characters, e.g. "
            "`openssl rand -hex 24`): the broker refuses anonymous clients"
        )
    _check_username(server_username)
    robots = sim_robots or []
    if robots and sim_password and len(sim_password) < MIN_BROKER_PASSWORD_LENGTH:
        raise ValueError(f"FLEET_SIM_ROBOT_PASSWORD is shorter than {MIN_BROKER_PASSWORD_LENGTH} characters")
    for rid in robots:
        check_robot_username(rid)
    passwd, acl = auth_dir / "passwd", auth_dir / "acl"
    done = []
    changed = ensure_broker_password(passwd, server_username, server_password)
    done.append(f"{passwd}: {server_username} {'set' if changed else 'unchanged'}")
    if robots and sim_password:
        for rid in robots:
            changed = ensure_broker_password(passwd, rid, sim_password)
            done.append(f"{passwd}: {rid} {'set' if changed else 'unchanged'}")
    elif robots:
        done.append("FLEET_SIM_ROBOT_PASSWORD empty: no accounts for the simulated robots")
    if not acl.exists():
        fd, tmp = tempfile.mkstemp(prefix=".acl-", dir=auth_dir)
        with os.fdopen(fd, "w") as f:
            f.write(acl_template.read_text())
        os.chmod(tmp, 0o600)
        os.replace(tmp, acl)
        done.append(f"{acl}: installed from {acl_template}")
    else:
        done.append(f"{acl}: kept")
    return done
