"""A parked robot keeps clear: after a goal ends by itself the robot stands with its motors off, and the water
or a neighbour may still bring it too near another. Then it moves as little as the safety filter asks
(:meth:`~robot_agent.motion.collision_guard.GuardedMotors.keep_clear`), within the geofence, and only while the
server supervises it.

A stop, the e-stop, a lost link, shutdown or a drive (:meth:`Parked.disarm`) leave it where it is: an operator
who stopped a robot, or lifts it from the water, is never surprised by it moving on its own. docs/safety.md."""

from __future__ import annotations

from collections.abc import Callable

from robot_agent.motion.collision_guard import GuardedMotors
from robot_agent.motion.controller import DriftObserver, Estimate
from robot_agent.motion.fence_guard import FenceGuard


class Parked:
    def __init__(
        self,
        *,
        collision: GuardedMotors | None,
        fence: FenceGuard,
        observer: DriftObserver,
        supervised: Callable[[], bool],
    ) -> None:
        self._collision = collision
        self._fence = fence
        self._observer = observer
        self._supervised = supervised
        #: it may keep clear: a goal ended by itself (done, or failed other than by a lost link) since the last
        #: stop, e-stop, lost link or drive
        self.armed = False

    @property
    def moving(self) -> bool:
        """It is keeping clear now (its motors run: the link watchdog watches)."""
        return self._collision is not None and self._collision.keeping_clear is not None

    def step(self, est: Estimate) -> None:
        """A position fix of the parked robot: move if it must, stand still if it need not."""
        collision = self._collision
        if collision is None or not (self.armed or self.moving):
            return
        wheels = collision.keep_clear() if self.armed and self._supervised() else None
        if wheels is not None and self._fence.motion_problem(est, wheels) is not None:
            wheels = None  # the fence comes first: it stands, and the neighbour's own filter keeps them apart
        if wheels is None:
            collision.end_keep_clear()
            self._observer.commanded(0.0, 0.0)
        else:  # the observer models what the motors really got: the move is not the water's drift
            self._observer.commanded(wheels.linear, wheels.angular)

    def halt(self) -> None:
        """Stand still now (its fix or the server went quiet): it keeps clear again once both are back."""
        if self.moving:
            assert self._collision is not None
            self._collision.end_keep_clear()
            self._observer.commanded(0.0, 0.0)

    def disarm(self) -> None:
        """Stop keeping clear, and stay parked until a goal ends by itself again."""
        self.armed = False
        self.halt()
