"""Reliability of the confidences (detector, triangulation, MVNet) against their true error, per round."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Query

from backend.api.deps import AdminUser, SessionDep, StorageDep
from backend.services.statistics import reliability as service

router = APIRouter(prefix="/admin/reliability", tags=["admin: reliability"])


@router.get("")
def reliability(session: SessionDep, storage: StorageDep, _admin: AdminUser,
                bins: int = Query(10, ge=1, le=service.MAX_BINS)) -> dict[str, Any]:
    """Per round and confidence source: equal-width confidence bins with their count and mean true error (the
    ground truth where the capture has one, else the accepted fit)."""
    return service.reliability(session, storage, bins=bins)
