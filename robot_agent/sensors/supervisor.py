"""Runs each sensor plugin in its own task; a failing plugin is reported and restarted with backoff.

A plugin fails when ``start()`` or ``run()`` raises (or ``run()`` returns). Its state becomes
``{"ok": false, "error": "..."}`` in the robot's status, it is stopped, and started again after an
exponentially growing delay (reset once it has run for ``stable_after_s``). The other plugins never notice.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from pydantic import ValidationError

from fleet_common.backoff import Backoff
from fleet_protocol import SensorState, is_valid_stream
from robot_agent.sensors.base import SensorConfig, SensorContext, SensorPlugin

log = logging.getLogger(__name__)


class SensorConfigError(ValueError):
    """A ``[[sensors]]`` entry is invalid (unknown type, bad field, duplicate stream)."""


def build_plugins(
    raw_configs: list[dict[str, Any]],
    registry: dict[str, type[SensorPlugin]],
    make_ctx: Callable[[], SensorContext],
) -> list[SensorPlugin]:
    """Validate every plugin config with its own model (extra="forbid") and instantiate the plugins."""
    plugins: list[SensorPlugin] = []
    streams: set[str] = set()
    for i, raw in enumerate(raw_configs):
        kind = raw.get("type")
        if not isinstance(kind, str) or kind not in registry:
            raise SensorConfigError(f"sensors[{i}]: unknown sensor type {kind!r} (known: {', '.join(registry)})")
        cls = registry[kind]
        try:
            cfg: SensorConfig = cls.config_model.model_validate(raw)
        except ValidationError as exc:
            raise SensorConfigError(f"sensors[{i}] ({kind}): {exc}") from None
        if not cfg.enabled:
            continue
        plugin = cls(cfg, make_ctx())
        if not is_valid_stream(plugin.stream):
            raise SensorConfigError(f"sensors[{i}] ({kind}): invalid stream name {plugin.stream!r}")
        if plugin.stream in streams:
            raise SensorConfigError(f"sensors[{i}] ({kind}): stream {plugin.stream!r} used twice")
        streams.add(plugin.stream)
        plugins.append(plugin)
    return plugins


@dataclass
class PluginHealth:
    ok: bool = True
    error: str | None = None
    starting: bool = True
    failures: int = 0
    emitted: int = 0
    rate_hz: float | None = None
    _rate_mark: tuple[float, int] = field(default_factory=lambda: (time.monotonic(), 0))

    def update_rate(self) -> None:
        t0, n0 = self._rate_mark
        t = time.monotonic()
        if t - t0 >= 1.0:
            self.rate_hz = round((self.emitted - n0) / (t - t0), 2)
            self._rate_mark = (t, self.emitted)


class SensorSupervisor:
    def __init__(
        self,
        plugins: list[SensorPlugin],
        on_health_change: Callable[[], None] = lambda: None,
        backoff_initial_s: float = 0.5,
        backoff_max_s: float = 30.0,
        stable_after_s: float = 10.0,
    ) -> None:
        self.plugins = plugins
        self.health: dict[str, PluginHealth] = {p.stream: PluginHealth() for p in plugins}
        self._on_change = on_health_change
        self.backoff_initial_s = backoff_initial_s
        self.backoff_max_s = backoff_max_s
        self.stable_after_s = stable_after_s
        self._tasks: list[asyncio.Task[None]] = []

    @property
    def names(self) -> list[str]:
        return [p.stream for p in self.plugins]

    def count_emit(self, stream: str) -> None:
        h = self.health.get(stream)
        if h is not None:
            h.emitted += 1

    def states(self) -> dict[str, SensorState]:
        out = {}
        for name, h in self.health.items():
            h.update_rate()
            out[name] = SensorState(ok=h.ok, error=h.error, rate_hz=h.rate_hz)
        return out

    def start(self) -> None:
        for p in self.plugins:
            self._tasks.append(asyncio.create_task(self._supervise(p), name=f"sensor:{p.stream}"))

    async def stop(self) -> None:
        for t in self._tasks:
            t.cancel()
        for t in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await t
        self._tasks.clear()

    def _set(self, p: SensorPlugin, ok: bool, error: str | None) -> None:
        h = self.health[p.stream]
        changed = (h.ok, h.error) != (ok, error)
        h.ok, h.error, h.starting = ok, error, False
        if changed:
            self._notify()

    def _notify(self) -> None:
        try:
            self._on_change()
        except Exception:
            log.exception("health change callback failed")

    async def _supervise(self, p: SensorPlugin) -> None:
        backoff = Backoff(self.backoff_initial_s, self.backoff_max_s)
        loop = asyncio.get_running_loop()
        while True:
            started = loop.time()
            try:
                await p.start()
                self._set(p, True, None)
                await p.run()
                raise RuntimeError("run() returned")
            except asyncio.CancelledError:
                await self._stop_plugin(p)
                raise
            except Exception as exc:
                h = self.health[p.stream]
                h.failures += 1
                error = f"{type(exc).__name__}: {exc}"[:300]
                if loop.time() - started >= self.stable_after_s:
                    backoff.reset()
                log.warning("sensor %s failed (%s); retrying in %.1fs", p.stream, error, backoff.delay)
                self._set(p, False, error)
            await self._stop_plugin(p)
            await asyncio.sleep(backoff.next())

    async def _stop_plugin(self, p: SensorPlugin) -> None:
        try:
            await asyncio.wait_for(p.stop(), 5.0)
        except Exception as exc:
            log.warning("sensor %s stop failed: %s", p.stream, exc)
