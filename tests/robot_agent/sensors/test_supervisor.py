"""Sensor supervision: a failing plugin is reported and retried with backoff; the others keep running."""

from __future__ import annotations

import asyncio
import time
from typing import Any

import pytest

from fleet_protocol import ImuData, LighthouseGeometry, PositionData
from robot_agent.sensors import SENSOR_REGISTRY
from robot_agent.sensors.base import SensorConfig, SensorContext, SensorPlugin
from robot_agent.sensors.supervisor import SensorConfigError, SensorSupervisor, build_plugins
from robot_agent.sim.world import Pose, SimWorld
from tests.support.procs import wait_until


class Emits:
    def __init__(self) -> None:
        self.msgs: list[tuple[str, dict[str, Any], bool]] = []

    def ctx(self, world: SimWorld | None = None) -> SensorContext:
        return SensorContext(
            robot_id="r1",
            emit=lambda s, d: self.msgs.append((s, d, False)),
            emit_retained=lambda s, d: self.msgs.append((s, d, True)),
            emit_camera=lambda s, b: None,
            world=world,
        )

    def of(self, stream: str) -> list[dict[str, Any]]:
        return [d for s, d, _ in self.msgs if s == stream]


class Counter(SensorPlugin):
    type_name = "counter"
    default_stream = "counter"

    async def read(self) -> dict[str, Any] | None:
        return {"t": time.monotonic()}


class Flaky(SensorPlugin):
    """Fails to start the first ``fail_starts`` times, then crashes in run after 3 samples once."""

    type_name = "flaky"
    default_stream = "flaky"
    starts = 0
    stops = 0

    async def start(self) -> None:
        type(self).starts += 1
        if type(self).starts <= 2:
            raise FileNotFoundError("/dev/flaky0 missing")

    async def stop(self) -> None:
        type(self).stops += 1

    async def read(self) -> dict[str, Any] | None:
        return {"ok": 1}


REG: dict[str, type[SensorPlugin]] = {"counter": Counter, "flaky": Flaky}


def test_failing_plugin_is_reported_and_retried_while_others_run() -> None:
    Flaky.starts = Flaky.stops = 0
    em = Emits()
    changes: list[dict[str, Any]] = []

    async def body() -> None:
        plugins = build_plugins([{"type": "counter", "rate_hz": 50}, {"type": "flaky", "rate_hz": 50}], REG, em.ctx)
        sup = SensorSupervisor(
            plugins,
            lambda: changes.append({k: v.ok for k, v in sup.health.items()}),
            backoff_initial_s=0.05,
            backoff_max_s=0.2,
        )
        sup.start()
        try:
            await wait_until(lambda: sup.states()["flaky"].ok is False, timeout=3, what="flaky's first failure")
            st = sup.states()
            assert st["flaky"].ok is False and "FileNotFoundError: /dev/flaky0 missing" in (st["flaky"].error or "")
            assert st["counter"].ok is True
            await wait_until(lambda: bool(em.of("flaky")), timeout=3, what="flaky recovered")
            assert sup.states()["flaky"].ok is True and sup.health["flaky"].failures == 2
        finally:
            await sup.stop()

    asyncio.run(body())
    assert Flaky.starts == 3
    assert Flaky.stops >= 3  # stopped after each failure and at shutdown
    assert len(em.of("counter")) >= 5
    assert any(c["flaky"] is False for c in changes) and changes[-1]["flaky"] is True


def test_backoff_grows_exponentially() -> None:
    class Never(SensorPlugin):
        type_name = "never"
        default_stream = "never"
        times: list[float] = []

        async def start(self) -> None:
            type(self).times.append(time.monotonic())
            raise RuntimeError("no device")

    async def body() -> None:
        sup = SensorSupervisor(
            build_plugins([{"type": "never"}], {"never": Never}, Emits().ctx), backoff_initial_s=0.05, backoff_max_s=10
        )
        sup.start()
        await wait_until(lambda: len(Never.times) >= 4, timeout=5, what="four start attempts")
        await sup.stop()

    asyncio.run(body())
    gaps = [b - a for a, b in zip(Never.times, Never.times[1:], strict=False)]
    assert len(gaps) >= 3
    assert gaps[0] == pytest.approx(0.05, abs=0.03)
    assert gaps[1] == pytest.approx(0.10, abs=0.04)
    assert gaps[2] == pytest.approx(0.20, abs=0.06)


def test_plugin_config_is_validated_strictly() -> None:
    em = Emits()
    with pytest.raises(SensorConfigError, match="unknown sensor type 'lidar'"):
        build_plugins([{"type": "lidar"}], SENSOR_REGISTRY, em.ctx)
    with pytest.raises(SensorConfigError, match="nope"):
        build_plugins([{"type": "imu", "nope": 1}], SENSOR_REGISTRY, em.ctx)
    with pytest.raises(SensorConfigError, match="used twice"):
        build_plugins([{"type": "imu"}, {"type": "position", "stream": "imu"}], SENSOR_REGISTRY, em.ctx)
    with pytest.raises(SensorConfigError, match="invalid stream"):
        build_plugins([{"type": "imu", "stream": "a/b"}], SENSOR_REGISTRY, em.ctx)
    assert build_plugins([{"type": "imu", "enabled": False}], SENSOR_REGISTRY, em.ctx) == []


def test_sim_position_and_imu_plugins_publish_valid_payloads() -> None:
    em = Emits()
    world = SimWorld(start=Pose(0.5, -0.5, 1.0))

    async def body() -> None:
        plugins = build_plugins(
            [{"type": "position", "rate_hz": 100}, {"type": "imu", "rate_hz": 100}],
            SENSOR_REGISTRY,
            lambda: em.ctx(world),
        )
        sup = SensorSupervisor(plugins)
        sup.start()
        await wait_until(
            lambda: (
                len(em.of("position")) >= 8
                and bool(em.of("imu"))
                and any(s == "lighthouse_geometry" for s, _d, _r in em.msgs)
            ),
            timeout=5,
            what="position, imu and the lighthouse geometry",
        )
        await sup.stop()

    asyncio.run(body())
    pos = em.of("position")
    assert len(pos) >= 8
    p = PositionData.model_validate(pos[-1])
    assert (p.x, p.y, p.z, p.yaw) == (pytest.approx(0.5), pytest.approx(-0.5), 0.0, pytest.approx(1.0))
    ImuData.model_validate(em.of("imu")[-1])
    geo = [(d, r) for s, d, r in em.msgs if s == "lighthouse_geometry"]
    assert len(geo) == 1 and geo[0][1] is True
    stations = LighthouseGeometry.model_validate(geo[0][0]).base_stations
    assert len(stations) == 2
    for bs in stations:  # proper rotations
        r = bs.rotation
        for i in range(3):
            for j in range(3):
                dot = sum(r[k][i] * r[k][j] for k in range(3))
                assert dot == pytest.approx(1.0 if i == j else 0.0, abs=1e-6)


def test_sim_sources_without_world_fail_start_and_are_reported() -> None:
    em = Emits()

    async def body() -> None:
        sup = SensorSupervisor(build_plugins([{"type": "position"}], SENSOR_REGISTRY, em.ctx), backoff_initial_s=5)
        sup.start()
        await wait_until(lambda: not sup.states()["position"].ok, timeout=3, what="the failed start reported")
        st = sup.states()["position"]
        assert not st.ok and "--simulate" in (st.error or "")
        await sup.stop()

    asyncio.run(body())


def test_base_station_geometry_comes_from_config() -> None:
    em = Emits()
    cfg: dict[str, Any] = {
        "type": "position",
        "base_stations": [{"id": "bs-a", "position": [1, 2, 3], "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}],
    }
    (plugin,) = build_plugins([cfg], SENSOR_REGISTRY, lambda: em.ctx(SimWorld()))
    asyncio.run(plugin.start())
    (geo,) = em.of("lighthouse_geometry")
    assert geo == {
        "base_stations": [
            {"id": "bs-a", "position": [1.0, 2.0, 3.0], "rotation": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}
        ]
    }
    assert isinstance(plugin.config, SensorConfig)
