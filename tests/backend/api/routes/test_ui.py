"""Dashboard files from FLEET_FRONTEND_DIR, offline Swagger UI, health shape."""

from __future__ import annotations

from tests.support.procs import ServerProcess


def test_dashboard_routes_and_assets(broker, database_url, workdir):
    front = workdir / "front"
    (front / "vendor").mkdir(parents=True)
    (front / "index.html").write_text("<!doctype html><title>fleet test</title>")
    (front / "app.js").write_text("console.log('fleet');")
    (front / "vendor" / "lib.js").write_text("/* vendored */")
    s = ServerProcess(broker, database_url, workdir, FLEET_FRONTEND_DIR=str(front))
    s.start()
    try:
        with s.client() as c:
            for path in ("/", "/robots/r1", "/history", "/users", "/runs", "/runs/7"):
                r = c.get(path)
                assert (
                    r.status_code == 200
                    and "fleet test" in r.text
                    and r.headers["content-type"].startswith("text/html")
                )
            assert c.get("/assets/app.js").text == "console.log('fleet');"
            assert c.get("/assets/vendor/lib.js").status_code == 200
            assert c.get("/assets/missing.js").status_code == 404
            assert c.get("/assets/../index.html").status_code == 404
    finally:
        s.stop()


def test_docs_work_offline_and_health(server):
    with server.client() as c:
        html = c.get("/docs").text
        assert "/static/swagger/swagger-ui-bundle.js" in html and "/static/swagger/swagger-ui.css" in html
        assert "cdn" not in html.lower() and "https://" not in html.replace("https://fastapi", "")
        assert c.get("/static/swagger/swagger-ui-bundle.js").status_code == 200
        assert c.get("/static/swagger/swagger-ui.css").status_code == 200
        spec = c.get("/openapi.json").json()
        assert "/api/robots/{robot_id}/commands" in spec["paths"]
        health = c.get("/api/health").json()
        assert health["status"] == "ok"
        assert health["mqtt"] == {"url": server.broker.url, "connected": True}
        assert health["database"]["ok"] is True and health["version"]
