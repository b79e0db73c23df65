"""One exception handler for the API: every error is ``{"detail": ..., "code": ...}`` (backend/core/errors.py),
a 405 names the methods the path really has (``Allow``), and :func:`errors` documents them per route."""

from __future__ import annotations

import functools
import math
import re
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import compile_path

from backend.api.deps import iter_api_routes
from backend.core.errors import ServiceError, error_json
from backend.schemas import ErrorBody


def errors(**described: str) -> dict[int | str, dict[str, Any]]:
    """``responses=`` for a route: ``errors(e404="unknown robot", e409="robot offline")``."""
    return {int(key[1:]): {"model": ErrorBody, "description": text} for key, text in described.items()}


def _allowed_methods(request: Request) -> list[str]:
    """Every method some route of this path answers (Starlette's own 405 names only the first route's)."""
    path = request.url.path
    methods: set[str] = set()
    for template, route_methods, _ in iter_api_routes(request.app):
        if route_methods != ["WS"] and _path_regex(template).match(path):
            methods.update(route_methods)
    return sorted(methods)


@functools.lru_cache(maxsize=512)
def _path_regex(template: str) -> re.Pattern[str]:
    return compile_path(template)[0]


async def _service_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ServiceError)
    return JSONResponse(error_json(exc.status_code, exc.detail, exc.code), exc.status_code, headers=exc.headers)


async def _http_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    headers = dict(exc.headers or {})
    if exc.status_code == 405:
        headers["Allow"] = ", ".join(_allowed_methods(request))
    code = getattr(exc, "code", None)
    return JSONResponse(error_json(exc.status_code, exc.detail, code), exc.status_code, headers=headers or None)


def _json_safe(value: Any) -> Any:
    """JSON has no NaN or infinity, but Python's parser reads them in a body: echo them back as text."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    return value


async def _validation_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    return JSONResponse(error_json(422, _json_safe(jsonable_encoder(exc.errors())), "validation_error"), 422)


def install_error_handlers(app: FastAPI) -> None:
    app.add_exception_handler(ServiceError, _service_error)
    app.add_exception_handler(StarletteHTTPException, _http_error)
    app.add_exception_handler(RequestValidationError, _validation_error)
