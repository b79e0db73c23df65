"""The dashboard (static files from FLEET_FRONTEND_DIR) and offline Swagger UI."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request
from fastapi.openapi.docs import get_swagger_ui_html
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
    "/missions",  # draw an area, pick robots, run and watch a mission (docs/missions.md)
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


@router.get("/docs")
async def swagger_ui(request: Request) -> HTMLResponse:
    return get_swagger_ui_html(
        openapi_url=str(request.app.openapi_url),
        title=f"{request.app.title} - API docs",
        swagger_js_url=f"{SWAGGER_STATIC}/swagger-ui-bundle.js",
        swagger_css_url=f"{SWAGGER_STATIC}/swagger-ui.css",
        swagger_favicon_url=f"{SWAGGER_STATIC}/favicon-32x32.png",
    )
