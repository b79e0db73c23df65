"""Hooks for ``schemathesis run`` (loaded through SCHEMATHESIS_HOOKS by test_openapi_all_checks.py).

Two rules of the API join two query parameters, which OpenAPI cannot state (it judges each parameter on its
own); the routes' descriptions say them and test_openapi_all_checks.py checks both refusals:
- ``start`` must not be after ``end`` (422);
- ``GET /api/telemetry`` streams raw rows as CSV or NDJSON only (``raw=true`` with ``format=json``: 422).
Right before each request (every phase), a generated pair that breaks one of them is put right (the times
swapped, csv for json); nothing else of the case changes, so an invalid case stays invalid. A raw page's
``cursor`` must be one the server returned (422 ``bad_cursor``): a case meant to be valid goes without one.

``PUT /api/site`` has rules of geometry no schema can state (simple polygons with an area, keep-outs inside
the boundary, unique tag ids: 422 with their own codes, checked by tests/backend/api/routes/test_site.py).
A body generated as valid that breaks one of them gets a boundary and keep-outs that are a pool and unique
tag ids; its other fields stay as generated, and a case generated as invalid is never touched."""

from __future__ import annotations

from typing import Any

import schemathesis

from backend.api.params import parse_time
from backend.services.site.geofence import SiteRefused, check_site

POOL = [[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]]


def _time(value: Any) -> float | None:
    try:
        return parse_time(value, "t") if isinstance(value, str) else None
    except Exception:
        return None


def _a_pool(body: Any) -> None:
    """Put right what only the server's geometry check refuses (an invalid case stays invalid)."""
    if not isinstance(body, dict) or not isinstance(body.get("boundary"), list):
        return
    try:
        check_site(body)
    except SiteRefused:
        body["boundary"] = POOL
        if isinstance(body.get("keepouts"), list):
            body["keepouts"] = []
        tags = body.get("tags")
        if isinstance(tags, list):
            unique: dict[Any, Any] = {}
            for t in tags:
                key = t.get("id") if isinstance(t, dict) else None
                unique.setdefault(key if isinstance(key, int | float | str) else id(t), t)
            body["tags"] = list(unique.values())
    except Exception:  # a shape the schema refuses anyway (the server answers 422 before the check)
        return


@schemathesis.hook
def before_call(ctx: schemathesis.HookContext, case: schemathesis.Case, **kwargs: Any) -> None:
    meta = getattr(case, "meta", None)
    positive = meta is not None and meta.generation.mode.is_positive
    if positive and case.operation.path == "/api/site" and case.operation.method.upper() == "PUT":
        _a_pool(case.body)  # only a case meant to be valid: a negative one must stay as generated
    query = case.query
    if not query:
        return
    if positive and "cursor" in query:
        del query["cursor"]  # a cursor is one the server returned (422 bad_cursor otherwise): none is known here
    if positive and "limit" in query and str(query.get("raw", "false")).lower() != "true":
        del query["limit"]  # limit pages raw rows only (422 with raw=false): joined, as the route says
    limit = query.get("limit")
    if positive and isinstance(limit, int) and limit > 10_000 and query.get("format", "json") == "json":
        # a raw JSON page holds at most 10,000 rows (422 over it); CSV/NDJSON pages up to a setting: joined
        query["limit"] = 10_000
    lo, hi = _time(query.get("start")), _time(query.get("end"))
    if lo is not None and hi is not None and lo > hi:
        query["start"], query["end"] = query["end"], query["start"]
    if case.operation.path == "/api/telemetry":
        raw = str(query.get("raw", "false")).lower() == "true"
        if raw and query.get("format", "json") == "json":
            query["format"] = "csv"
