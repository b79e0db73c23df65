"""Wi-Fi link quality from ``/proc/net/wireless`` (signal level) and ``iw dev IF link`` (bit rate).

Both are parsed as text and may be absent (no Wi-Fi, a wired robot, ``iw`` not installed): the result is
then None, never a default.
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

PROC_NET_WIRELESS = Path("/proc/net/wireless")
#: ``iw`` is a process start (milliseconds of CPU): the bit rate is refreshed this rarely
IW_PERIOD_S = 10.0
IW_TIMEOUT_S = 2.0

_BITRATE = re.compile(r"^\s*tx bitrate:\s*([0-9.]+)\s*MBit/s", re.MULTILINE)
_SIGNAL = re.compile(r"^\s*signal:\s*(-?[0-9.]+)\s*dBm", re.MULTILINE)


@dataclass(frozen=True, slots=True)
class WirelessLine:
    interface: str
    level_dbm: float | None


def _level_dbm(field: str) -> float | None:
    """The "level" column: dBm when negative; old drivers write an 8-bit value (dBm + 256)."""
    try:
        v = float(field.rstrip("."))
    except ValueError:
        return None
    if v < 0:
        return v
    if 64 <= v < 256:
        return v - 256
    return None  # 0 (no signal reported) or a relative quality: not dBm


def parse_proc_net_wireless(text: str) -> list[WirelessLine]:
    """The interface lines of /proc/net/wireless (after its two header lines)."""
    out = []
    for line in text.splitlines()[2:]:
        if ":" not in line:
            continue
        name, rest = line.split(":", 1)
        cols = rest.split()
        if len(cols) < 3:
            continue
        out.append(WirelessLine(name.strip(), _level_dbm(cols[2])))
    return out


def parse_iw_link(text: str) -> tuple[float | None, float | None]:
    """(signal dBm, tx bit rate Mbit/s) from ``iw dev IF link``; (None, None) when not connected."""
    if not text.strip() or text.lstrip().startswith("Not connected"):
        return None, None
    sig = _SIGNAL.search(text)
    rate = _BITRATE.search(text)
    return (float(sig.group(1)) if sig else None), (float(rate.group(1)) if rate else None)


def _running_loop() -> asyncio.AbstractEventLoop | None:
    try:
        return asyncio.get_running_loop()
    except RuntimeError:  # a sample taken outside the agent's loop: no background iw, the cached rate
        return None


class WifiReader:
    """Signal from /proc each sample (a file read); bit rate from ``iw``, run in the background."""

    def __init__(
        self, interface: str | None = None, proc_path: Path = PROC_NET_WIRELESS, iw_path: str | None = "auto"
    ) -> None:
        self.interface = interface
        self.proc_path = proc_path
        self.iw = shutil.which("iw") if iw_path == "auto" else iw_path
        self._iw_result: tuple[float | None, float | None] = (None, None)
        self._iw_at = -1e9
        self._iw_task: asyncio.Task[None] | None = None

    def read_proc(self) -> WirelessLine | None:
        try:
            text = self.proc_path.read_text(encoding="ascii", errors="replace")
        except OSError:
            return None
        lines = parse_proc_net_wireless(text)
        if self.interface is not None:
            return next((w for w in lines if w.interface == self.interface), None)
        return lines[0] if lines else None

    async def _run_iw(self, interface: str) -> None:
        assert self.iw is not None
        try:
            proc = await asyncio.create_subprocess_exec(
                self.iw,
                "dev",
                interface,
                "link",
                stdout=asyncio.subprocess.PIPE,
                stderr=asyncio.subprocess.DEVNULL,
            )
            try:
                out, _ = await asyncio.wait_for(proc.communicate(), IW_TIMEOUT_S)
            except TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    proc.kill()
                await proc.wait()
                self._iw_result = (None, None)
                return
            ok = proc.returncode == 0
            self._iw_result = parse_iw_link(out.decode(errors="replace")) if ok else (None, None)
        except OSError:
            self._iw_result = (None, None)

    def read(self) -> tuple[str | None, float | None, float | None]:
        """(interface, rssi dBm, bit rate Mbit/s). Starts an ``iw`` refresh when due, on the running loop."""
        line = self.read_proc()
        interface = line.interface if line else self.interface
        rssi = line.level_dbm if line else None
        rate: float | None = None
        if self.iw and interface:
            now = time.monotonic()
            idle = self._iw_task is None or self._iw_task.done()
            if now - self._iw_at >= IW_PERIOD_S and idle and (loop := _running_loop()) is not None:
                self._iw_at = now
                self._iw_task = loop.create_task(self._run_iw(interface))
            iw_rssi, rate = self._iw_result
            if rssi is None:
                rssi = iw_rssi
        return interface, rssi, rate

    def close(self) -> None:
        if self._iw_task is not None:
            self._iw_task.cancel()
