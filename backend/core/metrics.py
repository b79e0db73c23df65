"""Prometheus exposition through ``prometheus_client``: the counters and gauges come from the services' own
stats at scrape time (:class:`SnapshotCollector`), so /metrics and /api/stats never disagree; only the
command latency needs a histogram of its own, kept here (:class:`Histogram`)."""

from __future__ import annotations

import bisect
import math
import threading
from collections.abc import Iterable, Iterator, Mapping

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily, Metric
from prometheus_client.registry import Collector

#: seconds; command round trips on a LAN sit between a few ms and the ack timeout
LATENCY_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)
#: the media type of the text format the library writes
CONTENT_TYPE = CONTENT_TYPE_LATEST


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


class Exposition:
    """The metric families of one scrape; :meth:`render` writes them in the Prometheus text format."""

    def __init__(self) -> None:
        self._families: dict[str, Metric] = {}

    def family(self, name: str, kind: str, help_text: str, labels: Iterable[str] = ()) -> Metric:
        if name not in self._families:
            factory = {"counter": CounterMetricFamily, "gauge": GaugeMetricFamily}[kind]
            self._families[name] = factory(name, help_text, labels=list(labels))
        return self._families[name]

    def sample(self, name: str, value: float, labels: Mapping[str, str] | None = None) -> None:
        family = self._families[name]
        assert isinstance(family, CounterMetricFamily | GaugeMetricFamily)
        family.add_metric([str(v) for v in (labels or {}).values()], float(value))

    def metric(
        self, name: str, kind: str, help_text: str, value: float, labels: Mapping[str, str] | None = None
    ) -> None:
        self.family(name, kind, help_text, (labels or {}).keys())
        self.sample(name, value, labels)

    def histogram(self, name: str, help_text: str, hist: Histogram, label: str) -> None:
        family = HistogramMetricFamily(name, help_text, labels=[label])
        for value, (counts, total) in sorted(hist.snapshot().items()):
            running = 0
            buckets: list[tuple[str, float]] = []
            for bound, count in zip(hist.buckets, counts, strict=False):
                running += count
                buckets.append((repr(bound), running))
            buckets.append(("+Inf", running + counts[-1]))
            family.add_metric([value], buckets, total)
        self._families[name] = family

    def render(self) -> str:
        registry = CollectorRegistry(auto_describe=False)
        registry.register(SnapshotCollector(list(self._families.values())))
        return generate_latest(registry).decode()


class SnapshotCollector(Collector):
    """Hands the library the families built for one scrape."""

    def __init__(self, families: list[Metric]) -> None:
        self._families = families

    def collect(self) -> Iterator[Metric]:
        return iter(self._families)
