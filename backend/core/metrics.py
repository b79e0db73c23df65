"""Minimal Prometheus text exposition: counters and gauges come from the services' own stats; only the
command latency needs a histogram, kept here. No client library: the format is small and stable."""

from __future__ import annotations

import bisect
import math
import threading
from collections.abc import Iterable, Mapping

#: seconds; command round trips on a LAN sit between a few ms and the ack timeout
LATENCY_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)


class Histogram:
    """Cumulative-bucket histogram per label value (e.g. the ack status)."""

    def __init__(self, buckets: Iterable[float] = LATENCY_BUCKETS) -> None:
        self.buckets = tuple(sorted(buckets))
        self._lock = threading.Lock()
        self._counts: dict[str, list[int]] = {}
        self._sums: dict[str, float] = {}

    def observe(self, label: str, value: float) -> None:
        if not math.isfinite(value):
            return
        with self._lock:
            counts = self._counts.setdefault(label, [0] * (len(self.buckets) + 1))
            counts[bisect.bisect_left(self.buckets, value)] += 1
            self._sums[label] = self._sums.get(label, 0.0) + value

    def snapshot(self) -> dict[str, tuple[list[int], float]]:
        with self._lock:
            return {k: (list(v), self._sums[k]) for k, v in self._counts.items()}


def _escape(value: str) -> str:
    return value.replace("\\", "\\\\").replace("\n", "\\n").replace('"', '\\"')


def _labels(labels: Mapping[str, str]) -> str:
    if not labels:
        return ""
    return "{" + ",".join(f'{k}="{_escape(str(v))}"' for k, v in labels.items()) + "}"


class Exposition:
    """Builds the text format: ``# HELP``/``# TYPE`` once per family, then its samples."""

    def __init__(self) -> None:
        self._lines: list[str] = []
        self._declared: set[str] = set()

    def family(self, name: str, kind: str, help_text: str) -> None:
        if name not in self._declared:
            self._declared.add(name)
            self._lines.append(f"# HELP {name} {help_text}")
            self._lines.append(f"# TYPE {name} {kind}")

    def sample(self, name: str, value: float, labels: Mapping[str, str] | None = None) -> None:
        self._lines.append(f"{name}{_labels(labels or {})} {float(value)!r}")

    def metric(self, name: str, kind: str, help_text: str, value: float,
               labels: Mapping[str, str] | None = None) -> None:
        self.family(name, kind, help_text)
        self.sample(name, value, labels)

    def histogram(self, name: str, help_text: str, hist: Histogram, label: str) -> None:
        self.family(name, "histogram", help_text)
        for value, (counts, total) in sorted(hist.snapshot().items()):
            running = 0
            for bound, count in zip(hist.buckets, counts, strict=False):
                running += count
                self.sample(f"{name}_bucket", running, {label: value, "le": repr(bound)})
            running += counts[-1]
            self.sample(f"{name}_bucket", running, {label: value, "le": "+Inf"})
            self.sample(f"{name}_sum", total, {label: value})
            self.sample(f"{name}_count", running, {label: value})

    def render(self) -> str:
        return "\n".join(self._lines) + "\n"
