"""The dashboard (static files from FLEET_FRONTEND_DIR) and offline Swagger UI."""

from __future__ import annotations

from html import escape

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import FileResponse, HTMLResponse

from backend.api.deps import PUBLIC, SettingsDep

#: The UI shell is public (it holds no data; the data behind it needs a login).
router = APIRouter(include_in_schema=False, dependencies=[PUBLIC])

SWAGGER_STATIC = "/static/swagger"
#: Under FLEET_FRONTEND_DIR: swagger-ui-dist 5.x from npm (LICENSE, NOTICE next to it; see its README.md)
SWAGGER_DIR = "vendor/swagger-ui"


#: Every path the dashboard routes itself (frontend/js/app.js): each is served its shell, index.html.
DASHBOARD_PATHS = (
    "/",
    "/robots/{robot_id}",
    "/history",
    "/runs",
    "/runs/{run_id}",
    "/missions",  # the missions, and a mission drawn, run, watched and reported (docs/missions.md)
    "/missions/{mission_id}",
    "/users",  # users & tokens: the page asks the admin-only API, others see why they cannot
    "/audit",  # the audit trail, likewise admin-only behind it
)


def _page(settings: SettingsDep, name: str, what: str) -> FileResponse:
    page = settings.frontend_dir / name
    if not page.is_file():
        raise HTTPException(404, detail=f"{what} not found: {page} does not exist")
    return FileResponse(page, media_type="text/html", headers={"Cache-Control": "no-cache"})


async def dashboard(settings: SettingsDep) -> FileResponse:
    return _page(settings, "index.html", "dashboard")


for _path in DASHBOARD_PATHS:
    router.add_api_route(_path, dashboard, methods=["GET"])


@router.get("/login")
async def login_page(settings: SettingsDep) -> FileResponse:
    return _page(settings, "login.html", "login page")


#: FastAPI's Swagger page, less its inline script (the Content-Security-Policy runs none: core/headers.py):
#: frontend/js/apidocs.js starts Swagger UI with the same options, reading the schema's URL from the page.
DOCS_PAGE = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<link rel="stylesheet" href="{static}/swagger-ui.css">
<link rel="icon" href="{static}/favicon-32x32.png">
</head>
<body>
<div id="swagger-ui" data-openapi-url="{openapi_url}"></div>
<script src="{static}/swagger-ui-bundle.js"></script>
<script src="/assets/js/apidocs.js"></script>
</body>
</html>
"""


@router.get("/docs")
async def swagger_ui(request: Request) -> HTMLResponse:
    return HTMLResponse(
        DOCS_PAGE.format(
            title=escape(f"{request.app.title} - API docs"),
            static=SWAGGER_STATIC,
            openapi_url=escape(str(request.app.openapi_url)),
        )
    )
