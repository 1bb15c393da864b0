"""Static files the backend serves besides the API: the browser UI (frontend/, no build step) at / and
viser's single-file client at /viewer/ (the reviewers' 3D view)."""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles

from backend.viewer.client import client_dir

FRONTEND_DIR = Path(__file__).resolve().parents[2] / "frontend"


def mount(app: FastAPI) -> None:
    """After the API routers: the catch-all mount at / must come last."""
    app.mount("/viewer", StaticFiles(directory=client_dir(), html=True), name="viewer")
    app.mount("/", StaticFiles(directory=FRONTEND_DIR, html=True), name="frontend")
