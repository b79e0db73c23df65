"""One error type for every refusal a service makes, and the body every 4xx/5xx of the API carries:
``{"detail": ..., "code": ...}``. ``code`` is machine-readable and stable (``robot_offline``,
``estop_engaged``, ``unknown_robot``, ``validation_error``...), so a client can tell apart two answers
with the same status (e.g. the 409s); ``detail`` is for people and may change."""

from __future__ import annotations

from typing import Any

from pydantic import ValidationError

#: the code of an error raised without one of its own (a plain HTTPException), by status
DEFAULT_CODES: dict[int, str] = {
    400: "bad_request",
    401: "unauthorized",
    403: "forbidden",
    404: "not_found",
    405: "method_not_allowed",
    406: "not_acceptable",
    409: "conflict",
    413: "payload_too_large",
    415: "unsupported_media_type",
    422: "validation_error",
    429: "rate_limited",
    500: "internal_error",
    503: "unavailable",
    504: "timeout",
}


def default_code(status_code: int) -> str:
    return DEFAULT_CODES.get(status_code, "client_error" if status_code < 500 else "server_error")


class ServiceError(Exception):
    """A refusal with its HTTP status, a message for people and a stable ``code`` for programs."""

    def __init__(self, status_code: int, detail: str, code: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(detail)
        self.status_code = status_code
        self.detail = detail
        self.code = code
        self.headers = headers


def error_json(status_code: int, detail: Any, code: str | None = None) -> dict[str, Any]:
    return {"detail": detail, "code": code or default_code(status_code)}


def format_errors(exc: ValidationError) -> str:
    """A pydantic error as one line a person can act on: ``loc: message; ...`` (no input echoed back)."""
    parts = []
    for e in exc.errors(include_url=False, include_input=False):
        loc = ".".join(str(p) for p in e["loc"]) or "args"
        parts.append(f"{loc}: {e['msg']}")
    return "; ".join(parts)
