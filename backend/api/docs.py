"""The API docs at /docs: Swagger UI from the installed swagger-ui-bundle-v2 wheel, served by this server, so
they work on an offline network (FastAPI's page loads Swagger UI from a CDN) and need no inline script."""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import HTMLResponse, Response
from fastapi.staticfiles import StaticFiles
from swagger_ui_bundle import swagger_ui_path

STATIC_DIR = Path(__file__).resolve().parent / "static"
ASSETS = "/docs/assets"
PAGE = f"""<!doctype html>
<html lang="en">
<head>
  <meta charset="utf-8">
  <title>handloop API</title>
  <link rel="stylesheet" href="{ASSETS}/swagger-ui.css">
  <link rel="icon" href="{ASSETS}/favicon-32x32.png">
</head>
<body>
  <div id="swagger-ui"></div>
  <script src="{ASSETS}/swagger-ui-bundle.js"></script>
  <script src="{ASSETS}/swagger-ui-standalone-preset.js"></script>
  <script src="/docs/init.js"></script>
</body>
</html>
"""


def swagger_ui_dir() -> Path:
    return Path(swagger_ui_path)


def mount(app: FastAPI) -> None:
    """Before the UI's catch-all mount at /. Create the app with docs_url=None (FastAPI's own page uses a CDN)."""

    @app.get("/docs", include_in_schema=False)
    async def docs() -> HTMLResponse:
        return HTMLResponse(PAGE)

    @app.get("/docs/init.js", include_in_schema=False)
    async def init_script() -> Response:
        return Response((STATIC_DIR / "swagger-init.js").read_bytes(), media_type="text/javascript")

    app.mount(ASSETS, StaticFiles(directory=swagger_ui_dir()), name="docs-assets")
