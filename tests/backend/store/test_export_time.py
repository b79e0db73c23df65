"""The CSV export's ``time_utc`` column: the same instant as ``ts``, rounded to the microsecond exactly as
``datetime.fromtimestamp`` rounds (the export caches each second's text for speed)."""

from __future__ import annotations

import math
import random
from datetime import UTC, datetime

from backend.store.export import iso_utc


def test_iso_utc_matches_datetime_to_the_microsecond():
    rng = random.Random(5)
    values = [rng.uniform(-1e9, 4e9) for _ in range(50_000)]
    values += [math.floor(v) + k for v in values[:2000] for k in (5e-7, 0.9999995, 0.99999949, 0.25)]
    values += [0.0, -0.5, -1.0000005, 1795512421.25, 1795512421.9999996]
    wrong = [v for v in values if iso_utc(v) != datetime.fromtimestamp(v, tz=UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")]
    assert wrong == []
    assert iso_utc(1795512421.25) == "2026-11-24T09:27:01.250000Z"
