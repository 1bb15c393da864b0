"""All routers under /api."""

from __future__ import annotations

from fastapi import APIRouter

from backend.api.routes import annotate, auth, exports, files, health, imports, jobs, review, rounds, users
from backend.api.routes import activity, dashboard, overlays, prefetch, viewer  # the browser UI's routes
from backend.api.routes.annotation_set import router as annotation_set_router

api_router = APIRouter(prefix="/api")
for module in (health, auth, users, annotate, review, files, rounds, jobs, exports, imports):
    api_router.include_router(module.router)
api_router.include_router(annotation_set_router)  # admin: which samples people annotate (e.g. D_0)
for module in (prefetch, overlays, viewer, activity, dashboard):
    api_router.include_router(module.router)
