"""Label quality (issue 40): audit figures per round and stream, and the admin's quality settings."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from backend.api.deps import AdminUser, SessionDep
from backend.schemas.quality import GoldMark, GoldPublic, QualitySettingsIn, QualitySettingsPublic, QualitySummary
from backend.services.review import agreement, label_audits, precision_target
from backend.services.statistics.team_statistics import quality_over_time

router = APIRouter(prefix="/admin/quality", tags=["admin: label quality"])


@router.get("", response_model=QualitySummary)
def quality(session: SessionDep, _admin: AdminUser) -> dict[str, Any]:
    """Per round and stream: labels audited blind, found wrong, the share and its Wilson 95 % interval; the
    heuristic's thresholds the newest round chose and why; per person, their quality this week against their earlier
    weeks and the team median."""
    return {**label_audits.summary(session), "thresholds": precision_target.current(session),
            "agreement": agreement.summary(session), "people": quality_over_time(session)}


@router.put("/settings", response_model=QualitySettingsPublic)
def update_settings(body: QualitySettingsIn, session: SessionDep, admin: AdminUser) -> dict[str, Any]:
    """Change the audit share (and its seed), the precision target or the audits it needs; the fields given."""
    changes = {name: getattr(body, name) for name in body.model_fields_set}
    config = label_audits.update_config(session, admin.id, changes)
    return {name: getattr(config, name) for name in label_audits.FIELDS}


@router.get("/audits")
def audits(session: SessionDep, _admin: AdminUser) -> dict[str, Any]:
    """Every audit with its label (sample, fit and its parameters, round, stream), verdict and reason."""
    rows = label_audits.list_audits(session)
    return {"count": len(rows), "audits": rows}


@router.post("/gold", response_model=GoldPublic, status_code=201)
def mark_gold(body: GoldMark, session: SessionDep, admin: AdminUser) -> dict[str, Any]:
    """Mark an accepted label gold (known right): slipped unmarked into reviewers' queues (setting gold_share), each
    reviewer's agreement with it shown per person. 404 for a sample with no accepted label."""
    gold = label_audits.mark_gold(session, admin.id, body.sample_id)
    return {"sample_id": gold.sample_id, "fit_id": gold.fit_id, "stream": gold.stream}
