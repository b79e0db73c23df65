"""What a client of the live WebSocket (``/ws``) sends."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field


class Subscribe(BaseModel):
    type: Literal["subscribe"]
    robots: list[str] = Field(default_factory=lambda: ["*"], max_length=1000)
    streams: list[str] = Field(default_factory=lambda: ["*"], max_length=200)
