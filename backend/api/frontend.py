"""Static files the backend serves besides the API: the browser UI (frontend/, no build step) at / and
viser's single-file client at /viewer/ (the reviewers' 3D view)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from starlette.routing import Match, Mount

from backend.viewer.client import client_dir

FRONTEND_DIR = Path(__file__).resolve().parents[2] / "frontend"
API_PREFIX = "/api"


class UIMount(Mount):
    """The UI's catch-all mount at /, which never claims a path under /api: such a request is the API's to answer
    (a wrong method on an API path: 405 naming the allowed ones in `Allow`; an unknown API path: a JSON 404), not
    the static files' (which answered `OPTIONS /api/annotate/next` with 405 `Allow: GET, HEAD`)."""

    def matches(self, scope: dict[str, Any]) -> tuple[Match, dict[str, Any]]:
        path = scope.get("path", "")
        if path == API_PREFIX or path.startswith(API_PREFIX + "/"):
            return Match.NONE, {}
        return super().matches(scope)


def mount(app: FastAPI) -> None:
    """After the API routers: the catch-all mount at / must come last."""
    app.mount("/viewer", StaticFiles(directory=client_dir(), html=True), name="viewer")
    app.router.routes.append(UIMount("/", app=StaticFiles(directory=FRONTEND_DIR, html=True), name="frontend"))
