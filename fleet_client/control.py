"""``FleetClient.control(robot)``: an off-board controller's live poses and velocity set-points, on one
WebSocket to the server (``/ws/control/{robot}``).

    async with fleet.control("r1") as ctl:
        async for pose in ctl.poses():          # each new fix (the latest, if the loop fell behind)
            await ctl.drive(0.1, -1.0 * pose["y"])  # m/s, rad/s: a ``drive`` command, deadman renewed here

While the block runs, the last set-point is re-sent every ``1 / rate_hz`` seconds when the controller sent
none (the robot's deadman, ``duration_s``, stops it otherwise). When the block exits, or raises, the robot
is told to stop and the socket closes (the server stops it too when the socket goes). Set-points are sent
at most ``max_rate_hz`` a second on average (the server's command rate per caller and robot); a faster
controller's extra set-points are merged: only the latest one waiting is sent.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import time
from collections import OrderedDict
from collections.abc import AsyncIterator, Sequence
from typing import Any
from urllib.parse import quote, urlencode

from fleet_client.errors import ControlError, FleetError

#: The robot's deadman for each set-point: it stops this long after the last one that reached it.
DEFAULT_DEADMAN_S = 0.3
#: Re-send the last set-point this often when the controller sent none in the meantime.
DEFAULT_RATE_HZ = 10.0
#: The server's default command rate per caller and robot (FLEET_COMMAND_RATE_PER_S).
DEFAULT_MAX_RATE_HZ = 20.0
#: Set-points that may go at once above the average rate (the server's bucket allows 40).
SEND_BURST = 5.0
#: Refusals that end the block: the robot cannot be driven until a person acts.
FATAL_CODES = frozenset({"estop_engaged", "robot_held", "lease_held", "robot_offline", "battery_critical"})


class RobotControl:
    """The object ``async with client.control(robot) as ctl`` yields (see the module's docstring)."""

    def __init__(
        self,
        url: str,
        headers: dict[str, str],
        robot_id: str,
        *,
        rate_hz: float,
        duration_s: float,
        max_rate_hz: float,
    ) -> None:
        if not 0 < duration_s <= 5.0:
            raise ValueError("duration_s (the deadman) must be in (0, 5] s")
        if not 1.0 <= rate_hz <= 50.0:
            raise ValueError("rate_hz must be 1-50 Hz")
        if rate_hz * duration_s < 1.5:
            raise ValueError("the deadman must outlast at least 1.5 re-send periods (rate_hz * duration_s >= 1.5)")
        self.robot_id = robot_id
        self.duration_s = duration_s
        self._url = url
        self._headers = headers
        self._period = 1.0 / rate_hz
        self._max_rate = max_rate_hz
        self._tokens = SEND_BURST  # a token bucket like the server's: jitter passes, the average is capped
        self._tokens_at = time.monotonic()
        self._ws: Any = None
        self._tasks: list[asyncio.Task[None]] = []
        self._refs = itertools.count(1)
        #: the latest position data (with the envelope's ``ts`` and ``seq``) of each robot received
        self.latest: dict[str, dict[str, Any]] = {}
        self._pose_seq = 0
        self._pose_event = asyncio.Event()
        self._setpoint: tuple[float, float] | None = None  # None: stopped, nothing to renew
        self._pending: tuple[int, float, float] | None = None  # waiting for the rate
        self._last_send = -1e9
        self._send_lock = asyncio.Lock()
        self._wake_sender = asyncio.Event()
        #: ref -> command id of set-points the server published (the latest 1000)
        self.command_ids: OrderedDict[int, str] = OrderedDict()
        #: command id -> when the server published it (its ``ts``, the server's clock)
        self.published_at: OrderedDict[str, float] = OrderedDict()
        #: every ``error`` message the server answered (rate limits, refusals), and rejected drives' acks
        self.errors: list[dict[str, Any]] = []
        self.rejections: list[dict[str, Any]] = []
        self.fatal: ControlError | None = None
        self.robots: list[dict[str, Any]] = []
        self.estop: dict[str, Any] = {}
        self._ready = asyncio.Event()
        self._closed = asyncio.Event()
        self.sent = 0
        self.resent = 0
        self._stop_ref: int | None = None
        self._stop_sent = asyncio.Event()

    # -- life ---------------------------------------------------------------------------------------
    async def __aenter__(self) -> RobotControl:
        try:
            import websockets
        except ImportError as exc:  # pragma: no cover - depends on the installation
            raise FleetError(0, "client.control needs the websockets package (pip install websockets)") from exc
        try:
            self._ws = await websockets.connect(self._url, additional_headers=self._headers, max_size=None)
        except (OSError, websockets.exceptions.WebSocketException) as exc:
            raise FleetError(0, f"cannot open the control socket: {exc}") from exc
        self._tasks = [
            asyncio.create_task(self._receiver(), name=f"control-recv-{self.robot_id}"),
            asyncio.create_task(self._renewer(), name=f"control-renew-{self.robot_id}"),
        ]
        try:
            await asyncio.wait_for(self._ready.wait(), 10.0)
        except TimeoutError:
            await self._shutdown()
            raise FleetError(0, "the control socket sent no ready message within 10 s") from None
        if self.fatal is not None:
            await self._shutdown()
            raise self.fatal
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self._shutdown()

    async def _shutdown(self) -> None:
        """Stop the robot (and wait briefly for the server to publish the stop), then close."""
        self._setpoint = None
        self._pending = None
        renewer = self._tasks[1] if len(self._tasks) > 1 else None
        if renewer is not None:
            renewer.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await renewer
        if self._ws is not None and not self._closed.is_set():
            with contextlib.suppress(Exception):
                self._stop_ref = next(self._refs)
                await self._ws.send(json.dumps({"type": "stop", "ref": self._stop_ref}))
                await asyncio.wait_for(self._stop_sent.wait(), 2.0)
        for task in self._tasks:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        if self._ws is not None:
            with contextlib.suppress(Exception):
                await self._ws.close()

    # -- receiving ----------------------------------------------------------------------------------
    async def _receiver(self) -> None:
        try:
            async for frame in self._ws:
                for msg in json.loads(frame):
                    self._on_message(msg)
        except Exception as exc:  # the socket broke: the controller must not go on blind
            if self.fatal is None:
                self.fatal = ControlError("connection_lost", f"control socket lost: {exc}")
        else:
            if self.fatal is None:
                self.fatal = ControlError("connection_lost", "the server closed the control socket")
        finally:
            self._closed.set()
            self._ready.set()
            self._pose_event.set()

    def _on_message(self, msg: dict[str, Any]) -> None:
        kind = msg.get("type")
        if kind == "telemetry":
            if msg.get("stream") == "position":
                data = dict(msg["data"])
                data["ts"], data["seq"] = msg["ts"], msg["seq"]
                self.latest[msg["robot_id"]] = data
                if msg["robot_id"] == self.robot_id:
                    self._pose_seq += 1
                    self._pose_event.set()
        elif kind == "sent":
            ref = msg.get("ref")
            if isinstance(ref, int):
                self.command_ids[ref] = msg["id"]
                self.published_at[msg["id"]] = msg.get("ts", 0.0)
                while len(self.command_ids) > 1000:
                    self.command_ids.popitem(last=False)
                    self.published_at.popitem(last=False)
                if ref == self._stop_ref:
                    self._stop_sent.set()
        elif kind == "error":
            self.errors.append(msg)
            del self.errors[:-1000]
            if msg.get("code") in FATAL_CODES or msg.get("code") == "unknown_robot":
                self.fatal = ControlError(msg["code"], msg.get("detail", ""))
                self._pose_event.set()
        elif kind == "command":
            cmd = msg["command"]
            if cmd.get("robot_id") == self.robot_id and cmd.get("status") in ("rejected", "expired"):
                self.rejections.append(cmd)
                del self.rejections[:-1000]
        elif kind == "estop":
            self.estop = msg
        elif kind == "ready":
            self.robots = msg.get("robots", [])
            self.estop = msg.get("estop", {})
            for robot in self.robots:
                pos = robot.get("position")
                if pos:
                    self.latest.setdefault(robot["id"], dict(pos))
            self._ready.set()

    # -- poses --------------------------------------------------------------------------------------
    @property
    def pose(self) -> dict[str, Any] | None:
        """The robot's latest position data (x, y, yaw, ts, ...), or None before the first."""
        return self.latest.get(self.robot_id)

    def pose_of(self, robot_id: str) -> dict[str, Any] | None:
        """The latest pose of a robot in ``watch=`` (or this one)."""
        return self.latest.get(robot_id)

    def _raise_if_fatal(self) -> None:
        if self.fatal is not None:
            raise self.fatal

    async def next_pose(self, timeout: float | None = 2.0) -> dict[str, Any]:
        """Wait for a pose newer than the last one returned; ControlError when the robot sends none in
        ``timeout`` seconds (its fix or its link is gone) or the robot can no longer be driven."""
        self._raise_if_fatal()
        seq = self._pose_seq
        deadline = None if timeout is None else time.monotonic() + timeout
        while self._pose_seq == seq:
            self._pose_event.clear()
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                raise ControlError("no_position", f"no pose from {self.robot_id} for {timeout:g} s")
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(remaining):  # no task per wait, unlike wait_for on 3.11
                    await self._pose_event.wait()
            self._raise_if_fatal()
        pose = self.pose
        assert pose is not None
        return pose

    async def poses(self, timeout: float | None = 2.0) -> AsyncIterator[dict[str, Any]]:
        """Every new pose as it arrives (a slow loop gets the latest, never a backlog)."""
        while True:
            yield await self.next_pose(timeout)

    # -- set-points ---------------------------------------------------------------------------------
    async def drive(self, linear: float, angular: float = 0.0) -> int:
        """Set the velocity (m/s forward, rad/s counter-clockwise) until the next call; kept alive at
        ``rate_hz``. Returns the set-point's ref (``command_ids[ref]`` is its command id once published).
        Raises ControlError when the robot can no longer be driven (e-stop, hold, lease, offline, lost)."""
        self._raise_if_fatal()
        self._setpoint = (float(linear), float(angular))
        ref = next(self._refs)
        if self._pending is None and self._token_wait() <= 0:
            await self._send(ref, *self._setpoint)
        else:  # over the rate: the renewer sends the latest waiting set-point when its turn comes
            self._pending = (ref, *self._setpoint)
            self._wake_sender.set()
        return ref

    async def stop(self) -> None:
        """Stop now (a ``stop`` command) and renew nothing until the next :meth:`drive`."""
        self._setpoint = None
        self._pending = None
        await self._ws.send(json.dumps({"type": "stop", "ref": next(self._refs)}))

    def _token_wait(self) -> float:
        """Seconds until a set-point may go (0: now), refilling the bucket."""
        now = time.monotonic()
        self._tokens = min(SEND_BURST, self._tokens + (now - self._tokens_at) * self._max_rate)
        self._tokens_at = now
        return 0.0 if self._tokens >= 1.0 else (1.0 - self._tokens) / self._max_rate

    async def _send(self, ref: int, linear: float, angular: float) -> None:
        async with self._send_lock:
            self._last_send = time.monotonic()
            self._token_wait()
            self._tokens -= 1.0
            msg = {"type": "drive", "linear": linear, "angular": angular, "duration_s": self.duration_s, "ref": ref}
            try:
                await self._ws.send(json.dumps(msg))
            except Exception as exc:
                self.fatal = self.fatal or ControlError("connection_lost", f"control socket lost: {exc}")
                raise self.fatal from exc
            self.sent += 1

    async def _renewer(self) -> None:
        """Sends a set-point held back by the rate, and re-sends the last one when none went for a period."""
        while True:
            self._wake_sender.clear()
            now = time.monotonic()
            if self._pending is not None:
                wait = self._token_wait()
                if wait <= 0:
                    pending, self._pending = self._pending, None
                    await self._send(*pending)
                    continue
            elif self._setpoint is not None:
                wait = self._last_send + self._period - now
                if wait <= 0:
                    self.resent += 1
                    await self._send(next(self._refs), *self._setpoint)
                    continue
            else:
                wait = self._period
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(max(wait, 0.001)):
                    await self._wake_sender.wait()


def control_url(base: str, robot_id: str, watch: Sequence[str], streams: Sequence[str], client_id: str) -> str:
    scheme = "wss" if base.startswith("https") else "ws"
    query = {
        k: v for k, v in {"watch": ",".join(watch), "streams": ",".join(streams), "client": client_id}.items() if v
    }
    tail = f"?{urlencode(query)}" if query else ""
    return f"{scheme}://{base.split('://', 1)[1]}/ws/control/{quote(robot_id, safe='')}{tail}"
