"""Query parameter parsing shared by routes."""

from __future__ import annotations

import math
from datetime import UTC, datetime

from fastapi import HTTPException


def parse_time(value: str | None, name: str) -> float | None:
    """ISO 8601 (naive = UTC) or epoch seconds -> epoch seconds; 422 with a message otherwise."""
    if value is None or value == "":
        return None
    try:
        t = float(value)
    except ValueError:
        pass
    else:
        if not math.isfinite(t):
            raise HTTPException(422, detail=f"{name}: must be a finite number of epoch seconds or ISO 8601")
        return t
    try:
        dt = datetime.fromisoformat(value)
    except ValueError:
        raise HTTPException(
            422, detail=f"{name}: {value[:60]!r} is neither epoch seconds nor an ISO 8601 time"
        ) from None
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=UTC)
    return dt.timestamp()


def parse_range(start: str | None, end: str | None) -> tuple[float | None, float | None]:
    lo, hi = parse_time(start, "start"), parse_time(end, "end")
    if lo is not None and hi is not None and lo > hi:
        raise HTTPException(422, detail="start must not be after end")
    return lo, hi
