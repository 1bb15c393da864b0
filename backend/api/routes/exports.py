"""Admin exports of the server's records: the accepted dataset, the sample index, MVNet's predictions.
The FreiHAND-layout files are written by `handloop export --format freihand` from the same records
(it needs the hand model and torch, which the API process does not load)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Query

from backend.api.deps import AdminUser, SessionDep
from backend.services import export

router = APIRouter(prefix="/admin/exports", tags=["admin: exports"])
# A project's name as a query parameter: PostgreSQL text cannot hold NUL, so it is a 422 here, not at the query.
ProjectQuery = Query(default=None, min_length=1, max_length=200, pattern=r"^[^\x00]*$")


@router.get("/dataset")
def export_dataset(session: SessionDep, _admin: AdminUser,
                   up_to_round: int | None = Query(default=None, ge=0, le=1_000_000),
                   project: str | None = ProjectQuery) -> dict[str, Any]:
    """The accepted samples (D_i up to a round index) with their fits, rounds and streams, and the hand
    models that made the labels."""
    return export.dataset(session, up_to_round, project)


@router.get("/samples")
def export_samples(session: SessionDep, _admin: AdminUser,
                   project: str | None = ProjectQuery) -> dict[str, Any]:
    """Every sample: id, sequence (external id), frame, split, state, current fit."""
    return export.sample_index(session, project)


@router.get("/predictions")
def export_predictions(session: SessionDep, _admin: AdminUser,
                       round_index: int | None = Query(default=None, ge=0, le=1_000_000)) -> dict[str, Any]:
    """MVNet's predictions with their round, keypoints (world frame, metres) and confidences."""
    return export.predictions(session, round_index)
