"""What the annotate and review pages draw: proposals and review overlays (services.display.overlays)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Query

from backend.api.deps import AnnotatorUser, ReviewerUser, SessionDep, SettingsDep
from backend.schemas.base import Id
from backend.schemas.ui import ProposalsPublic, ReviewOverlayPublic
from backend.services.display import overlays

router = APIRouter(tags=["overlays"])


@router.get("/annotate/samples/{sample_id}/proposals", response_model=ProposalsPublic)
def proposals(sample_id: Id, session: SessionDep, settings: SettingsDep, user: AnnotatorUser) -> dict[str, Any]:
    """Calibrations (to triangulate from your clicks), MVNet's and the current fit's keypoints in every view
    (the fit's with the keypoints its mesh hides per view), the previous clicks and the reviewer's note, for a
    sample whose annotation lease you hold."""
    return overlays.annotate_proposals(session, user, sample_id, mano_path=settings.mano_path)


@router.get("/review/samples/{sample_id}/overlay", response_model=ReviewOverlayPublic)
def review_overlay(sample_id: Id, session: SessionDep, settings: SettingsDep, user: ReviewerUser,
                   mesh: bool = Query(default=True, description="Include the fit's mesh.")) -> dict[str, Any]:
    """The fit's keypoints and mesh, per-view IoU and residuals, and a ticket for the 3D scene, for a sample
    whose review lease you hold."""
    return overlays.review_overlay(session, user, sample_id, secret_key=settings.signing_key,
                                   mano_path=settings.mano_path, with_mesh=mesh)
