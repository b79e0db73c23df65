"""The robot computer's own state: SoC temperature, CPU load, memory, disk, uptimes (psutil and sysfs)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

#: cpu_load needs at least this much time since the previous reading
MIN_CPU_INTERVAL_S = 0.1
THERMAL_ZONE = Path("/sys/class/thermal/thermal_zone0/temp")


def read_cpu_temp_c(path: Path = THERMAL_ZONE) -> float | None:
    """The Pi's SoC temperature (millidegrees in sysfs); psutil's first sensor where sysfs has none."""
    try:
        return round(int(path.read_text().strip()) / 1000.0, 2)
    except (OSError, ValueError):
        pass
    try:
        import psutil

        temps: dict[str, list[Any]] = psutil.sensors_temperatures() if hasattr(psutil, "sensors_temperatures") else {}
    except Exception:
        return None
    for entries in temps.values():
        for entry in entries:
            if entry.current is not None:
                return round(float(entry.current), 2)
    return None


class SystemReader:
    """psutil-backed readings; every method returns None when psutil (or the value) is unavailable."""

    def __init__(self, disk_path: Path = Path("/"), thermal_path: Path = THERMAL_ZONE) -> None:
        self.disk_path = disk_path
        self.thermal_path = thermal_path
        self._tried_temp = False
        self._no_temp = False
        try:
            import psutil
        except ImportError:
            self._psutil: Any = None
            self._process: Any = None
            self._process_started: float | None = None
            return
        self._psutil = psutil
        self._process = psutil.Process()
        self._process_started = self._process.create_time()
        psutil.cpu_percent(interval=None)  # starts the interval: the first sample then measures something
        self._cpu_mark = time.monotonic()

    def cpu_load(self) -> float | None:
        """% of all cores since the previous call; None when that interval is too short to mean anything."""
        if self._psutil is None:
            return None
        now = time.monotonic()
        too_short = now - self._cpu_mark < MIN_CPU_INTERVAL_S
        if too_short:
            return None  # psutil would answer 0.0 over a few microseconds: unmeasured, not idle
        self._cpu_mark = now
        return float(self._psutil.cpu_percent(interval=None))

    def mem_used_pct(self) -> float | None:
        return None if self._psutil is None else float(self._psutil.virtual_memory().percent)

    def disk_free_mb(self) -> float | None:
        if self._psutil is None:
            return None
        try:
            return round(self._psutil.disk_usage(str(self.disk_path)).free / 1e6, 1)
        except OSError:
            return None

    def agent_uptime_s(self) -> float | None:
        if self._process_started is None:
            return None
        return round(max(0.0, time.time() - self._process_started), 1)

    def system_uptime_s(self) -> float | None:
        if self._psutil is None:
            return None
        return round(max(0.0, time.time() - self._psutil.boot_time()), 1)

    def cpu_temp_c(self) -> float | None:
        if self._no_temp:  # neither sysfs nor psutil had one at the first try: do not scan hwmon every second
            return None
        temp = read_cpu_temp_c(self.thermal_path)
        self._no_temp = temp is None and self._tried_temp
        self._tried_temp = True
        return temp
