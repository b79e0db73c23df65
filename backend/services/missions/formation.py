"""A formation mission's fast loop: the formation law of fleet_common/formation.py (the same code as
``examples/formation.py``) run by the server on the robots' live positions.

The mission service's tick (5 Hz) is too slow to steer by, so each running formation mission has its own
task: it polls the registry's latest positions every ``POLL_S`` and, on each new fix of a follower, steps
that follower's law from the leader's fitted track and sends a ``drive`` with a short deadman. No fix, no
drive: a follower whose fixes stop (or a server that stops) stands within the deadman. The task never
changes the mission itself (it runs outside the service's lock): a refused drive is reported in
``refused`` and the service's tick drops that follower.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Awaitable, Callable

from backend.services.fleet.registry import Registry
from fleet_common.formation import FormationGains, LeaderTrack, SlotFollower

log = logging.getLogger(__name__)

#: How often the registry's positions are looked at (the fixes come at 20 Hz).
POLL_S = 0.02
#: Each drive's deadman: a follower stands this long after its last set-point.
DRIVE_DEADMAN_S = 0.3

#: ``send(robot_id, linear, angular)``: sends a drive; returns a refusal's reason, or None when it went out.
SendDrive = Callable[[str, float, float], Awaitable[str | None]]


class FormationDriver:
    """Steers one mission's followers to their slots around its leader."""

    def __init__(
        self,
        *,
        leader: str,
        slots: dict[str, tuple[float, float]],
        registry: Registry,
        send: SendDrive,
        gains: FormationGains | None = None,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.leader = leader
        self.gains = gains or FormationGains()
        self.track = LeaderTrack(window_s=self.gains.window_s)
        self.laws = {rid: SlotFollower(offset, self.gains) for rid, offset in slots.items()}
        self._registry = registry
        self._send = send
        self._clock = clock
        self._seen: dict[str, float] = {}
        self._stopped = False
        self._task: asyncio.Task[None] | None = None
        #: followers whose drive was refused (robot id -> reason), for the service to drop
        self.refused: dict[str, str] = {}
        self.sent = 0

    @property
    def running(self) -> bool:
        return self._task is not None and not self._task.done()

    def start(self, name: str) -> None:
        self._stopped = False
        self._task = asyncio.get_running_loop().create_task(self._run(), name=name)

    def stop(self) -> None:
        """No drive goes out after this returns (the caller stops the robots)."""
        self._stopped = True
        if self._task is not None:
            self._task.cancel()

    async def wait_stopped(self) -> None:
        if self._task is not None:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._task

    def slot_errors(self) -> dict[str, float]:
        """Each follower's distance from its slot at its last step (metres)."""
        return {rid: round(law.error_m, 4) for rid, law in self.laws.items()}

    async def _run(self) -> None:
        while not self._stopped:
            try:
                await self.step()
            except Exception:  # a bug must not leave the followers driving: no drive, the deadman stops them
                log.exception("formation step failed")
            await asyncio.sleep(POLL_S)

    def _new_fix(self, robot_id: str) -> tuple[float, float, float, float] | None:
        st = self._registry.get(robot_id)
        pos = st.position if st is not None else None
        if pos is None or pos.yaw is None or pos.ts <= self._seen.get(robot_id, 0.0):
            return None
        self._seen[robot_id] = pos.ts
        return pos.x, pos.y, pos.yaw, pos.ts

    async def step(self) -> None:
        """Take the leader's new fix, then drive each follower that has a new one."""
        lead = self._new_fix(self.leader)
        if lead is not None:
            self.track.update(*lead)
        for rid, law in self.laws.items():
            if self._stopped:
                return
            if rid in self.refused:
                continue
            me = self._new_fix(rid)
            if me is None:
                continue
            linear, angular = law.step(*me, self.track, self._clock())
            why = await self._send(rid, linear, angular)
            if why is not None:
                self.refused[rid] = why
            else:
                self.sent += 1
