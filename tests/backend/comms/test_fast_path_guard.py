"""The PUBLISH fast path runs only on the paho release it was proven against, with the private members it
touches as they were; anything else (or FLEET_MQTT_FAST_PATH=false) falls back to paho's own parser and
says so in the log and in the bridge's stats (/api/stats). The fallback loses nothing."""

from __future__ import annotations

import asyncio
import inspect
import logging
import re
import tomllib
from pathlib import Path

import paho.mqtt
import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from backend.comms import fast_path
from backend.comms.base import AckToken, InboundMessage, Subscription
from backend.comms.mqtt_bridge import PAHO_BRIDGE_PRIVATE_MEMBERS, MqttBridge
from tests.support.mqtt import MqttProbe
from tests.support.procs import Broker, ServerProcess, wait_until

REPO = Path(__file__).resolve().parents[3]


def test_the_installed_paho_is_the_tested_release_and_the_pin_says_so() -> None:
    assert paho.mqtt.__version__ == fast_path.TESTED_PAHO_VERSION
    deps = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    assert f"paho-mqtt=={fast_path.TESTED_PAHO_VERSION}" in deps


def test_the_private_members_the_fast_path_touches_are_there_with_their_kind_and_signature() -> None:
    assert fast_path.paho_member_changes() == []
    # the table itself, spelled out: a change of paho that moves any of these fails here
    assert tuple(inspect.signature(mqtt.Client._create_socket).parameters) == ("self",)
    assert tuple(inspect.signature(mqtt.Client._packet_queue).parameters) == (
        "self",
        "command",
        "packet",
        "mid",
        "qos",
        "info",
    )
    client = mqtt.Client(CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5)
    assert client._in_packet["command"] == 0 and client._sock is None
    assert client._protocol == mqtt.MQTTv5 and isinstance(client._last_bytes_received, float)
    with client._msgtime_mutex:
        pass
    assert set(fast_path.PAHO_PRIVATE_MEMBERS) == {
        "_create_socket",
        "_packet_queue",
        "_in_packet",
        "_sock",
        "_protocol",
        "_msgtime_mutex",
        "_last_bytes_received",
    }


def test_the_private_members_the_bridge_itself_touches_are_there() -> None:
    assert PAHO_BRIDGE_PRIVATE_MEMBERS == ("_sock_close", "_protocol", "_clean_session")
    assert tuple(inspect.signature(mqtt.Client._sock_close).parameters) == ("self",)
    v311 = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="x", protocol=mqtt.MQTTv311, clean_session=False)
    assert v311._clean_session is False and v311._protocol == mqtt.MQTTv311


def test_a_changed_member_is_reported(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mqtt.Client, "_packet_queue", lambda self, command, packet: None)
    problems = fast_path.paho_member_changes()
    assert len(problems) == 1 and "_packet_queue" in problems[0]
    assert fast_path.choose_fast_path(True)[0] is False


@pytest.mark.parametrize(
    ("version", "wanted", "on", "why"),
    [
        (fast_path.TESTED_PAHO_VERSION, True, True, r"^on \(paho-mqtt "),
        (fast_path.TESTED_PAHO_VERSION, False, False, r"^off \(FLEET_MQTT_FAST_PATH=false\)"),
        ("2.3.0", True, False, r"^off: paho-mqtt 2\.3\.0 is not the tested "),
    ],
)
def test_the_choice(monkeypatch: pytest.MonkeyPatch, version: str, wanted: bool, on: bool, why: str) -> None:
    monkeypatch.setattr(paho.mqtt, "__version__", version)
    chosen, state = fast_path.choose_fast_path(wanted)
    assert chosen is on and re.search(why, state), state


@pytest.mark.parametrize("cause", ["other-paho", "setting"])
def test_the_fallback_uses_pahos_parser_says_so_and_loses_nothing(
    broker: Broker, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture, cause: str
) -> None:
    if cause == "other-paho":
        monkeypatch.setattr(paho.mqtt, "__version__", "2.3.0")
    probe = MqttProbe(broker.host, broker.port, ["out/#"])
    got: list[InboundMessage] = []
    acked: list[list[AckToken]] = []

    async def scenario() -> None:
        bridge: MqttBridge | None = None

        def on_ack_marker(tokens: list[AckToken]) -> None:
            acked.append(tokens)
            assert bridge is not None
            bridge.ack(tokens)

        with caplog.at_level(logging.WARNING, logger="backend.comms.mqtt_bridge"):
            bridge = MqttBridge(
                broker.url,
                [Subscription("in/#", 1)],
                got.extend,
                client_id=f"bridge-fallback-{cause}",
                on_ack_marker=on_ack_marker,
                fast_path=cause != "setting",
            )
        bridge.start(asyncio.get_running_loop())
        try:
            await wait_until(lambda: bridge.connected)
            for i in range(50):
                await asyncio.to_thread(probe.publish, f"in/{i}", str(i).encode(), i % 2)
            await wait_until(lambda: len(got) == 50)
            await wait_until(lambda: bridge.stats()["acks_sent"] == 25)
            stats = bridge.stats()
        finally:
            await bridge.stop()
        assert sorted(int(m.payload) for m in got) == list(range(50))
        assert stats["parsed_without_paho"] == 0 and stats["callback_errors"] == 0
        assert stats["fast_path"].startswith("off"), stats["fast_path"]
        if cause == "other-paho":
            assert "2.3.0 is not the tested" in stats["fast_path"]
            assert any("fast path off: paho-mqtt 2.3.0" in r.getMessage() for r in caplog.records)

    try:
        asyncio.run(scenario())
    finally:
        probe.close()
    assert sum(len(t) for t in acked) == 25


def test_api_stats_says_whether_the_fast_path_runs(broker: Broker, database_url: str, workdir: Path) -> None:
    for setting, expected in (("true", "on (paho-mqtt "), ("false", "off (FLEET_MQTT_FAST_PATH=false)")):
        server = ServerProcess(broker, database_url, workdir, FLEET_MQTT_FAST_PATH=setting)
        server.start()
        try:
            with server.client() as http:
                state = http.get("/api/stats").json()["mqtt"]["fast_path"]
            assert state.startswith(expected), state
        finally:
            server.stop()
