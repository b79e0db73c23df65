"""The security headers of every HTTP response, the Content-Security-Policy among them: the one place they are
set (backend/main.py adds this middleware outermost, so the site guard's refusals carry them too)."""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

#: Every page and asset is the server's own (no CDN, nothing inline): nothing else may run, load, frame the
#: pages or be posted to. No ``'unsafe-eval'``: the vendored Plotly is a strict build (its WebGL draw calls
#: precompiled, not made with ``Function``: scripts/plotly-bundle). No ``'unsafe-inline'`` for styles either:
#: Plotly's rules come from vendor/plotly.css instead of a ``<style>`` it would insert, and the dashboard
#: sets styles only through CSSOM (``element.style``), which CSP allows. ``data:``/``blob:`` images: Swagger
#: UI's icons, Plotly's PNG download. ``connect-src 'self'`` also covers the page's own ``ws:``/``wss:``
#: (CSP Level 3: Chromium 70+, Firefox, Safari since 2022).
CONTENT_SECURITY_POLICY = "; ".join(
    (
        "default-src 'self'",
        "script-src 'self'",
        "style-src 'self'",
        "img-src 'self' data: blob:",
        "connect-src 'self'",
        "object-src 'none'",
        "base-uri 'self'",
        "form-action 'self'",
        "frame-ancestors 'none'",
    )
)


class SecurityHeadersMiddleware:
    """Adds each header a response does not set itself (no route does: a test holds every page to the
    policy above, tests/backend/api/test_site_guard.py)."""

    HEADERS = (
        (b"x-content-type-options", b"nosniff"),
        (b"x-frame-options", b"DENY"),
        (b"referrer-policy", b"no-referrer"),
        (b"content-security-policy", CONTENT_SECURITY_POLICY.encode()),
    )

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                present = {k.lower() for k, _ in message.get("headers", [])}
                message["headers"] = [
                    *message.get("headers", []),
                    *((k, v) for k, v in self.HEADERS if k not in present),
                ]
            await send(message)

        await self.app(scope, receive, with_headers)
