"""The OpenAPI document, told true: what FastAPI derives from the routes, plus every error a route can
answer (401/403 from its role, 404 from an unknown robot in its path, 400/413 from a JSON body, 422 from
its parameters), each with the body every error carries (``{"detail", "code"}``, backend/core/errors.py).
Public routes say that credentials are optional."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

from fastapi import FastAPI
from fastapi.dependencies.models import Dependant
from fastapi.openapi.utils import get_openapi

from backend.api.deps import PUBLIC_MARK, get_robot, iter_api_routes, route_role
from backend.schemas import ErrorBody

ERROR_REF = {"$ref": "#/components/schemas/ErrorBody"}


def _calls(dependant: Dependant) -> Iterator[Callable[..., Any]]:
    for dep in dependant.dependencies:
        if dep.call is not None:
            yield dep.call
        yield from _calls(dep)


def _implied_errors(dependant: Dependant) -> dict[str, str]:
    role = route_role(dependant)
    out: dict[str, str] = {}
    if role is not None and role != PUBLIC_MARK:
        out["401"] = "no credentials, or invalid, expired or revoked ones (code unauthorized)"
        out["403"] = "the caller's role is too low, or a cross-origin write with the session cookie (code forbidden)"
    if get_robot in set(_calls(dependant)):
        out["404"] = "unknown robot (code unknown_robot)"
    if dependant.body_params:
        out["400"] = "the body is not valid JSON (code bad_request)"
        out["413"] = "the body is larger than FLEET_MAX_BODY_BYTES (code payload_too_large)"
    if dependant.body_params or dependant.query_params or dependant.path_params:
        out["422"] = "invalid parameters or body (code validation_error, or a more specific one)"
    return out


def _document(schema: dict[str, Any], app: FastAPI) -> None:
    components = schema.setdefault("components", {}).setdefault("schemas", {})
    components["ErrorBody"] = ErrorBody.model_json_schema(ref_template="#/components/schemas/{model}")
    components.pop("HTTPValidationError", None)
    components.pop("ValidationError", None)
    for path, methods, dependant in iter_api_routes(app):
        if methods == ["WS"]:
            continue
        for method in methods:
            operation = schema["paths"].get(path, {}).get(method.lower())
            if operation is None:
                continue
            responses = operation.setdefault("responses", {})
            for status, description in _implied_errors(dependant).items():
                responses.setdefault(status, {"description": description})
            for status, response in responses.items():
                if status.isdigit() and int(status) >= 400:
                    content = response.setdefault("content", {})
                    json_body = content.get("application/json", {}).get("schema")
                    if json_body is None or json_body.get("$ref", "").endswith("/HTTPValidationError"):
                        content["application/json"] = {"schema": ERROR_REF}
            if route_role(dependant) == PUBLIC_MARK and operation.get("security"):
                operation["security"] = [{}, *operation["security"]]  # credentials optional


def truthful_openapi(app: FastAPI) -> Callable[[], dict[str, Any]]:
    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
            _document(schema, app)
            app.openapi_schema = schema
        return app.openapi_schema

    return openapi
