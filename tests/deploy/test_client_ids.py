"""The server's MQTT client id under the shipped Mosquitto config and ACL (deploy/mosquitto/).

Mosquitto closes the connection already using a client id when any account connects with the same id
("Client X already connected, closing old connection."): it cannot bind ids to accounts. So a robot account
that knows the server's id can keep it off the broker. Here two server replicas and the legacy sentinel share
the ``fleet-server`` account; a robot account then connects with every id it could guess (the configured
names), and the broker must never close one of theirs. A restarted replica resumes its own session."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

from backend.comms.client_id import SUFFIX_FILE
from tests.deploy.test_acl_safety import _files, _PlainBroker
from tests.deploy.test_mosquitto import Client, shipped_broker
from tests.support.procs import VENV_BIN, ServerProcess, base_env, wait_for

NAMES = ("fleet-server-a", "fleet-server-b")
SENTINEL = "legacy-sentinel"  # docker-compose.yml's FLEET_MQTT_CLIENT_ID for the sentinel
TAKEOVER = re.compile(r"Client (\S+) already connected, closing old connection")


def _connected_as(log: str, user: str) -> list[str]:
    return re.findall(rf"New client connected from \S+ as (\S+) \(.*u'{user}'\)", log)


def test_no_other_account_can_take_over_the_servers_or_the_sentinels_client_id(tmp_path: Path) -> None:
    with shipped_broker("auth", _files()) as b:
        url = f"mqtt://fleet-server:pw-server@127.0.0.1:{b.port}"
        servers = [
            ServerProcess(
                _PlainBroker(b.port, url),  # type: ignore[arg-type]
                f"sqlite:///{tmp_path / name / 'fleet.db'}",
                (tmp_path / name),
                FLEET_MQTT_CLIENT_ID=name,
            )
            for name in NAMES
        ]
        sentinel_log = tmp_path / "sentinel.log"
        sentinel: subprocess.Popen[bytes] | None = None
        heartbeats = Client(b.port, username="fleet-server", password="pw-server", subscribe=("fleet/heartbeat",))
        try:
            for name, s in zip(NAMES, servers, strict=True):
                (tmp_path / name).mkdir()
                s.start()
            with open(sentinel_log, "wb") as out:
                sentinel = subprocess.Popen(
                    [str(VENV_BIN / "fleet-server"), "legacy-sentinel"],
                    env=base_env(FLEET_MQTT_URL=url, FLEET_MQTT_CLIENT_ID=SENTINEL),
                    stdout=out,
                    stderr=subprocess.STDOUT,
                )
            wait_for(lambda: "legacy sentinel watching" in sentinel_log.read_text(), 30, what="the sentinel")
            heartbeats.wait_connected()
            heartbeats.wait_for_topic("fleet/heartbeat", count=4)

            # the detector works: a robot account taking over its own id is logged as a takeover
            first = Client(b.port, client_id="snail-1-probe", username="snail-1", password="pw-1")
            first.wait_connected()
            again = Client(b.port, client_id="snail-1-probe", username="snail-1", password="pw-1")
            again.wait_connected()
            assert first.dropped.wait(10), "the broker did not close the first snail-1-probe"
            # a robot account tries every id it could know or guess: the configured names
            for guess in (*NAMES, SENTINEL, "fleet-server"):
                attacker = Client(b.port, client_id=guess, username="snail-1", password="pw-1")
                attacker.wait_connected()
                attacker.close()
            again.close()

            # what other people see is the name, never the suffix
            suffixes = {n: (tmp_path / n / "server-data" / SUFFIX_FILE).read_text().strip() for n in NAMES}
            for name, s in zip(NAMES, servers, strict=True):
                assert (tmp_path / name / "server-data" / SUFFIX_FILE).stat().st_mode & 0o077 == 0
                with s.client() as c:
                    stats = c.get("/api/stats").text
                assert f'"client_id":"{name}"' in stats and suffixes[name] not in stats
            beats = b"".join(p for _, p in heartbeats.got)
            assert all(s.encode() not in beats for s in suffixes.values()) and b"fleet-server-a" in beats

            # a restarted replica comes back under its own id and resumes its session
            servers[0].stop()
            servers[0] = ServerProcess(
                _PlainBroker(b.port, url),  # type: ignore[arg-type]
                f"sqlite:///{tmp_path / NAMES[0] / 'fleet.db'}",
                (tmp_path / NAMES[0]),
                FLEET_MQTT_CLIENT_ID=NAMES[0],
            )
            servers[0].start()
            with servers[0].client() as c:
                assert c.get("/api/stats").json()["mqtt"]["session_present"] is True
        finally:
            heartbeats.close()
            if sentinel is not None:
                sentinel.terminate()
                sentinel.wait(10)
            for s in servers:
                s.stop()
        b.stop()  # Mosquitto's log reaches its file when it stops
        log = b.output()

    assert TAKEOVER.findall(log) == ["snail-1-probe"], log[-3000:]
    ids = _connected_as(log, "fleet-server")
    a, b_, sentinel_id = ([i for i in ids if i.startswith(f"{n}-")] for n in (NAMES[0], NAMES[1], SENTINEL))
    assert a == [f"{NAMES[0]}-{suffixes[NAMES[0]]}"] * 2, ids  # the same id before and after the restart
    assert b_ == [f"{NAMES[1]}-{suffixes[NAMES[1]]}"], ids
    assert len(sentinel_id) == 1 and re.fullmatch(rf"{SENTINEL}-[0-9a-f]{{32}}", sentinel_id[0]), ids
    assert suffixes[NAMES[0]] != suffixes[NAMES[1]]
