"""All routers under /api."""

from __future__ import annotations

from fastapi import APIRouter

from backend.api.routes import (
    activity,
    annotate,
    annotation_set,
    auth,
    calibration,
    dashboard,
    exports,
    files,
    guidelines,
    health,
    imports,
    jobs,
    overlays,
    preannotation,
    prefetch,
    quality,
    reliability,
    review,
    rounds,
    team,
    users,
    viewer,
)

api_router = APIRouter(prefix="/api")
# The service's own resources, then the admin's choice of what people annotate (e.g. D_0) or the detector
# pre-annotates, then the routes the browser UI needs (prefetch, overlays, 3D scenes, activity timing, dashboard).
for module in (health, auth, users, annotate, review, files, rounds, jobs, exports, imports, annotation_set,
               preannotation, prefetch, overlays, viewer, activity, dashboard, reliability, calibration,
               team, guidelines, quality):
    api_router.include_router(module.router)
