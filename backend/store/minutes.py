"""The minute a timestamp falls in, in Python and in SQL: the unit of the rollup tables' dirty marks."""

from __future__ import annotations

import math


def minute_of(ts: float) -> float:
    return math.floor(ts / 60.0) * 60.0


def minute_sql(dialect: str, col: str = "ts") -> str:
    """SQL for the start of ``col``'s minute (epoch seconds are positive: truncation is floor in SQLite)."""
    if dialect == "postgresql":
        return f"(floor({col} / 60.0) * 60.0)"
    return f"(CAST({col} / 60 AS INTEGER) * 60.0)"
