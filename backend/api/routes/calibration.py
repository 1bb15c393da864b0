from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from backend.api.deps import AdminUser, SessionDep
from backend.schemas.base import Id
from backend.services.captures.calibration_check import calibration_check

router = APIRouter(prefix="/admin/projects", tags=["admin: calibration"])


@router.get("/{project_id}/calibration-check")
def project_calibration_check(project_id: Id, session: SessionDep, admin: AdminUser) -> dict[str, Any]:
    """Per camera and camera pair, how well the annotators' visible clicks agree with the calibration;
    `flagged` names cameras that disagree with the others (read-only)."""
    return calibration_check(session, project_id)
