"""All routers under /api."""

from __future__ import annotations

from fastapi import APIRouter

from backend.api.routes import annotate, auth, exports, files, health, imports, jobs, review, rounds, users

api_router = APIRouter(prefix="/api")
for module in (health, auth, users, annotate, review, files, rounds, jobs, exports, imports):
    api_router.include_router(module.router)
