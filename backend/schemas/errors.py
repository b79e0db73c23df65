"""The body every error response carries (``detail`` for people, ``code`` for programs)."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field


class ErrorBody(BaseModel):
    """What every error response carries."""

    detail: str | list[dict[str, Any]] = Field(description="for people: what was wrong (may change)")
    code: str = Field(description="for programs: what kind of error (stable), e.g. robot_offline")
