"""Query parameter parsing shared by routes."""

from __future__ import annotations

import math
from datetime import UTC, datetime
from typing import Annotated

from fastapi import HTTPException, Query

# A time in a query: epoch seconds, or an ISO 8601 date or date-time (naive = UTC) with real calendar days
# (Feb 29 in leap years only). In the schema as a pattern, so that what the schema allows the server takes.
_YEAR = r"[1-9][0-9]{3}"
_LEAP_YEAR = r"([1-9][0-9](0[48]|[2468][048]|[13579][26])|([2468][048]|[13579][26])00)"
_MONTH_DAY = r"((0[1-9]|1[0-2])-(0[1-9]|1[0-9]|2[0-8])|(0[13-9]|1[0-2])-(29|30)|(0[13578]|1[02])-31)"
_DATE = rf"({_YEAR}-{_MONTH_DAY}|{_LEAP_YEAR}-02-29)"
_TIME = r"([01][0-9]|2[0-3]):[0-5][0-9](:[0-5][0-9](\.[0-9]{1,6})?)?"
_ZONE = r"(Z|[+-]([01][0-9]|2[0-3]):[0-5][0-9])?"
_EPOCH = r"-?[0-9]{1,11}(\.[0-9]{1,9})?"
TIME_PATTERN = rf"^(|{_EPOCH}|{_DATE}([T ]{_TIME}{_ZONE})?)$"

StartQ = Annotated[
    str | None, Query(pattern=TIME_PATTERN, max_length=40, description="ISO 8601 (naive = UTC) or epoch seconds")
]
EndQ = Annotated[
    str | None, Query(pattern=TIME_PATTERN, max_length=40, description="ISO 8601 (naive = UTC) or epoch seconds")
]


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
