"""The demo's Mosquitto queues, persists and drops like the lab's (scripts/demo_broker.py): its queue,
in-flight and persistence settings are the ones of deploy/mosquitto/mosquitto.conf, and a real Mosquitto
runs with the generated file and saves its state where the demo keeps it."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.mqtt import MqttProbe
from tests.support.procs import free_port, wait_for, wait_port

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))
import demo_broker  # noqa: E402  (scripts/ is not a package: demo.py imports it the same way)


def _settings(text: str) -> dict[str, str]:
    out = {}
    for line in text.splitlines():
        key, _, value = line.strip().partition(" ")
        if key in demo_broker.SHARED_BROKER_SETTINGS:
            out[key] = value
    return out


def test_demo_broker_takes_the_labs_queue_and_persistence_settings(tmp_path: Path) -> None:
    shipped = _settings((ROOT / "deploy" / "mosquitto" / "mosquitto.conf").read_text())
    conf = demo_broker.demo_mosquitto_conf(1883, tmp_path)
    assert _settings(conf) == shipped
    assert shipped["persistence"] == "true" and int(shipped["max_queued_messages"]) >= 100_000
    assert f"persistence_location {tmp_path}/" in conf

    changed = tmp_path / "changed.conf"  # a change to the lab's file reaches the demo
    changed.write_text(
        (ROOT / "deploy" / "mosquitto" / "mosquitto.conf")
        .read_text()
        .replace("max_queued_messages 100000", "max_queued_messages 123")
    )
    assert "max_queued_messages 123" in demo_broker.shipped_broker_settings(changed)
    changed.write_text("persistence true\n")
    with pytest.raises(RuntimeError, match="no longer sets"):
        demo_broker.shipped_broker_settings(changed)


def test_a_real_mosquitto_runs_the_demo_config_and_keeps_retained_state_across_a_restart(tmp_path: Path) -> None:
    exe = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    demo_dir = tmp_path / "demo"
    demo_dir.mkdir()
    port = free_port()
    conf = demo_dir / "mosquitto.conf"
    conf.write_text(demo_broker.demo_mosquitto_conf(port, demo_broker.broker_data_dir(demo_dir)))
    assert f"listener {port} 127.0.0.1\n" in conf.read_text()  # this machine only unless the demo has --lan
    log = demo_dir / "mosquitto.log"

    def start() -> subprocess.Popen[bytes]:
        with open(log, "ab") as f:
            proc = subprocess.Popen([exe, "-c", str(conf)], stdout=f, stderr=subprocess.STDOUT)
        wait_port(port)
        return proc

    proc = start()
    try:
        probe = MqttProbe("127.0.0.1", port)
        probe.publish("demo/retained", b"kept", retain=True)
        probe.close()
        proc.terminate()
        proc.wait(10)
        assert (demo_dir / "mosquitto-data" / "mosquitto.db").exists()
        proc = start()
        probe = MqttProbe("127.0.0.1", port, ["demo/retained"])
        wait_for(lambda: probe.matching(lambda m: m.payload == b"kept"), 10, what="the retained message")
        probe.close()
    finally:
        proc.terminate()
        proc.wait(10)
    assert "Error" not in log.read_text(errors="replace"), log.read_text()
