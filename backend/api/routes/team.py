"""Per-person statistics on the admin page (services.statistics.team_statistics)."""

from __future__ import annotations

from fastapi import APIRouter

from backend.api.deps import AdminUser, SessionDep
from backend.schemas.team import PersonStatistics
from backend.services.statistics.team_statistics import team_statistics

router = APIRouter(prefix="/admin/team", tags=["admin: team"])


@router.get("/statistics", response_model=list[PersonStatistics])
def statistics(session: SessionDep, _admin: AdminUser) -> list[dict]:
    """Per user: samples, clicks, seconds per sample and accept rate of their annotations; decisions, seconds
    per decision and overturned decisions of their reviews (definitions: docs/api.md)."""
    return team_statistics(session)
