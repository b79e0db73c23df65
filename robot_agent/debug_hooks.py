"""Fault injection for the safety tests. Nothing here exists unless ``FLEET_AGENT_DEBUG_HOOKS=1`` is set in
the agent's environment (never by default, never by a config file); the agent then logs a warning at start.

* ``SIGUSR1`` freezes the agent's event loop for ``FLEET_AGENT_DEBUG_FREEZE_S`` seconds (default 2) with a
  busy loop on the loop's own thread: what a stalled handler, a deadlock or a CPU-bound bug looks like.
* ``FLEET_AGENT_DEBUG_NO_MOTOR_WATCHDOG=1`` runs without the motor watchdog, to show a test can fail.
* ``FLEET_AGENT_DEBUG_CLOCK_SKEW_S=S`` moves the agent's wall clock by S seconds (clock-sync tests).
"""

from __future__ import annotations

import asyncio
import logging
import os
import signal
import time
from collections.abc import Mapping
from dataclasses import dataclass

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class DebugOptions:
    freeze_s: float = 2.0
    motor_watchdog: bool = True
    clock_skew_s: float = 0.0


def debug_options(env: Mapping[str, str] = os.environ) -> DebugOptions | None:
    if env.get("FLEET_AGENT_DEBUG_HOOKS") != "1":
        return None
    return DebugOptions(
        freeze_s=float(env.get("FLEET_AGENT_DEBUG_FREEZE_S", "2")),
        motor_watchdog=env.get("FLEET_AGENT_DEBUG_NO_MOTOR_WATCHDOG") != "1",
        clock_skew_s=float(env.get("FLEET_AGENT_DEBUG_CLOCK_SKEW_S", "0")),
    )


def freeze_loop(seconds: float) -> None:
    """Hold the calling thread (the event loop's) busy for ``seconds``."""
    log.warning("DEBUG: freezing the event loop for %.2f s", seconds)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass
    log.warning("DEBUG: event loop running again")


def install(loop: asyncio.AbstractEventLoop, opts: DebugOptions) -> None:
    log.warning("DEBUG HOOKS ENABLED (FLEET_AGENT_DEBUG_HOOKS=1): %s; never run a real robot like this", opts)
    loop.add_signal_handler(signal.SIGUSR1, freeze_loop, opts.freeze_s)
