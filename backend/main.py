"""App factory. Services are built in the lifespan and kept on ``app.state`` (no module globals)."""

from __future__ import annotations

import gc
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles

from backend import __version__
from backend.api.deps import WebSocketDenied, check_route_roles, websocket_denied_handler
from backend.api.errors import install_error_handlers
from backend.api.main import api_router
from backend.api.openapi import truthful_openapi
from backend.api.routes.ui import SWAGGER_DIR, SWAGGER_STATIC
from backend.core.config import Settings
from backend.core.headers import SecurityHeadersMiddleware
from backend.core.security import BodySizeLimitMiddleware, RepeatedQueryMiddleware, install_log_redaction
from backend.core.site_guard import SiteGuardMiddleware, parse_allowed_hosts
from backend.services.access.auth import AuthService
from backend.services.access.sockets import SocketHolders
from backend.services.container import build_services

log = logging.getLogger(__name__)


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    settings: Settings = app.state.settings
    services = await build_services(settings)
    app.state.services = services
    auth = AuthService(settings, services.engine, passwords=services.passwords)
    app.state.auth = auth
    auth.start()
    sockets = app.state.sockets = SocketHolders(engine=services.engine)  # who holds each open WebSocket now
    sockets.start()
    # Everything built so far lives as long as the server: out of the collector's way. Otherwise each full
    # (generation 2) collection walks all of it and stopped the event loop for ~130 ms under load (seen as
    # command round-trip p99 spikes); frozen, a full collection takes ~7 ms (bench/bench_live.py).
    gc.freeze()
    log.info(
        "fleet server %s: mqtt %s, database %s, auth %s",
        __version__,
        settings.mqtt_url_redacted,
        settings.database_url_redacted,
        "on" if settings.auth else "OFF",
    )
    try:
        yield
    finally:
        await sockets.stop()
        await auth.stop()
        await services.stop()


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()
    app = FastAPI(
        title="Mollusca Fleet",
        version=__version__,
        lifespan=lifespan,
        docs_url=None,  # served by routes/ui.py with local Swagger UI files (no CDN)
        redoc_url=None,
    )
    app.state.settings = settings
    app.include_router(api_router)
    check_route_roles(app)  # deny by default: every route declares who may call it
    app.add_exception_handler(WebSocketDenied, websocket_denied_handler)
    install_error_handlers(app)
    app.openapi = truthful_openapi(app)  # type: ignore[method-assign]
    app.add_middleware(BodySizeLimitMiddleware, max_bytes=settings.max_body_bytes)
    app.add_middleware(RepeatedQueryMiddleware)
    # a foreign Host or Origin is refused before anything else looks at the request
    app.add_middleware(
        SiteGuardMiddleware,
        allowed_hosts=parse_allowed_hosts(settings.allowed_hosts),
        allowed_origins=settings.allowed_origin_set,
    )
    # outermost: every response gets the security headers and the Content-Security-Policy, refusals too
    app.add_middleware(SecurityHeadersMiddleware)
    install_log_redaction()
    app.mount("/assets", StaticFiles(directory=settings.frontend_dir, check_dir=False), name="assets")
    # Swagger UI 5.x (reads OpenAPI 3.1), vendored from npm swagger-ui-dist with its licence files
    app.mount(
        SWAGGER_STATIC, StaticFiles(directory=settings.frontend_dir / SWAGGER_DIR, check_dir=False), name="swagger"
    )
    return app
