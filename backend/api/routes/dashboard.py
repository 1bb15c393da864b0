from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from backend.api.deps import AdminUser, SessionDep, SettingsDep
from backend.schemas.ui import DashboardPublic
from backend.services.statistics import dashboard

router = APIRouter(prefix="/admin/dashboard", tags=["admin: dashboard"])


@router.get("", response_model=DashboardPublic)
def get_dashboard(session: SessionDep, settings: SettingsDep, _admin: AdminUser) -> dict[str, Any]:
    """Queue lengths (free and leased), whether a round can be launched, MVNet confidence histogram,
    sparsification curve, human time per action."""
    return dashboard.dashboard(session, settings.round_min_training_samples)
