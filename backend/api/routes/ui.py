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


def _index(settings: SettingsDep) -> FileResponse:
    index = settings.frontend_dir / "index.html"
    if not index.is_file():
        raise HTTPException(404, detail=f"dashboard not found: {index} does not exist")
    return FileResponse(index, media_type="text/html", headers={"Cache-Control": "no-cache"})


@router.get("/")
async def dashboard(settings: SettingsDep) -> FileResponse:
    return _index(settings)


@router.get("/login")
async def login_page(settings: SettingsDep) -> FileResponse:
    page = settings.frontend_dir / "login.html"
    if not page.is_file():
        raise HTTPException(404, detail=f"login page not found: {page} does not exist")
    return FileResponse(page, media_type="text/html", headers={"Cache-Control": "no-cache"})


@router.get("/robots/{robot_id}")
async def robot_page(robot_id: str, settings: SettingsDep) -> FileResponse:
    return _index(settings)


@router.get("/history")
async def history_page(settings: SettingsDep) -> FileResponse:
    return _index(settings)


@router.get("/runs")
async def runs_page(settings: SettingsDep) -> FileResponse:
    return _index(settings)


@router.get("/runs/{run_id}")
async def run_page(run_id: str, settings: SettingsDep) -> FileResponse:
    return _index(settings)


@router.get("/missions")
async def missions_page(settings: SettingsDep) -> FileResponse:
    """Missions: draw an area, pick robots, run and watch a coverage mission (docs/missions.md)."""
    return _index(settings)


@router.get("/users")
async def users_page(settings: SettingsDep) -> FileResponse:
    """Users & tokens (the page asks the admin-only API; others see why they cannot)."""
    return _index(settings)


@router.get("/audit")
async def audit_page(settings: SettingsDep) -> FileResponse:
    """The audit trail (the page asks the admin-only API; others see why they cannot)."""
    return _index(settings)


@router.get("/docs")
async def swagger_ui(request: Request) -> HTMLResponse:
    return get_swagger_ui_html(
        openapi_url=str(request.app.openapi_url),
        title=f"{request.app.title} - API docs",
        swagger_js_url=f"{SWAGGER_STATIC}/swagger-ui-bundle.js",
        swagger_css_url=f"{SWAGGER_STATIC}/swagger-ui.css",
        swagger_favicon_url=f"{SWAGGER_STATIC}/favicon-32x32.png",
    )
