"""The server's health (``GET /api/health``)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel


class MqttHealth(BaseModel):
    url: str | None  # null for unauthenticated callers
    connected: bool


class DatabaseHealth(BaseModel):
    url: str | None  # null for unauthenticated callers
    ok: bool


class HealthPublic(BaseModel):
    status: Literal["ok", "degraded"]
    version: str
    #: "on", or "off" (FLEET_AUTH=off: demo only)
    auth: Literal["on", "off"] = "on"
    mqtt: MqttHealth
    database: DatabaseHealth
    rejects: dict[str, Any] | None  # null for unauthenticated callers
