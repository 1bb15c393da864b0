"""Label quality (issue 40): the admin's settings and the audit figures (services.review.label_audits)."""

from __future__ import annotations

from typing import Any

from pydantic import Field

from backend.schemas.base import Id, Public, Strict


class QualitySettingsIn(Strict):
    """A change of the quality settings: the fields given are changed, the others kept. `precision_target` null
    goes back to the paper's fixed thresholds."""

    audit_share: float = Field(default=None, ge=0, le=1, allow_inf_nan=False,  # type: ignore[assignment]
                               description="Share of each stream's accepted labels audited blind, 0..1.")
    audit_seed: int = Field(default=None, ge=0, le=2**31 - 1,  # type: ignore[assignment]
                            description="Picks which labels the share takes.")
    precision_target: float | None = Field(default=None, gt=0, lt=1, allow_inf_nan=False,
                                           description="At most this share of auto-accepted labels wrong "
                                                       "(e.g. 0.02); null: the paper's fixed thresholds.")
    min_audits_for_target: int = Field(default=None, ge=1, le=1_000_000,  # type: ignore[assignment]
                                       description="Audited heuristic labels needed before the thresholds are "
                                                   "chosen from them.")

    auditor_error_rate: float = Field(default=None, ge=0, lt=0.5, allow_inf_nan=False,  # type: ignore[assignment]
                                      description="How often an auditor's verdict is itself wrong, 0..0.5 (from "
                                                  "gold samples): the corrected figures undo it.")

    gold_share: float = Field(default=None, ge=0, le=1, allow_inf_nan=False,  # type: ignore[assignment]
                              description="Share of a reviewer's tasks that are gold labels, 0..1.")
    agreement_share: float = Field(default=None, ge=0, le=1, allow_inf_nan=False,  # type: ignore[assignment]
                                   description="Share of annotated samples a second annotator annotates blind, 0..1.")


class QualitySettingsPublic(Public):
    audit_share: float
    audit_seed: int
    precision_target: float | None
    min_audits_for_target: int
    auditor_error_rate: float
    gold_share: float
    agreement_share: float


class GoldMark(Strict):
    sample_id: Id = Field(description="An accepted sample: its label becomes gold (known right).")


class GoldPublic(Public):
    sample_id: int
    fit_id: int | None
    stream: str


class GoldAgreement(Public):
    user_id: int
    gold_judged: int
    gold_agreed: int = Field(description="Gold labels the reviewer accepted (a gold label is known right).")
    agreement: float | None
    agreement_ci95: list[float] | None = Field(description="Wilson 95 % interval of agreement.")


class AuditFigure(Public):
    audited: int = Field(description="Audits decided.")
    wrong: int = Field(description="Of them, labels the auditor found wrong (rejected or sent back).")
    pending: int = Field(description="Audits not yet decided.")
    error_rate: float | None = Field(description="wrong / audited; null before the first audit.")
    error_rate_ci95: list[float] | None = Field(description="Wilson 95 % interval of error_rate, [low, high].")
    error_rate_corrected: float | None = Field(description="The share wrong after the auditors' own error rate.")
    error_rate_corrected_ci95: list[float] | None = Field(description="error_rate_ci95, corrected likewise.")


class RoundAuditFigure(AuditFigure):
    round: int | None = Field(description="The index of the round the label was accepted in.")
    stream: str


class QualitySummary(Public):
    settings: QualitySettingsPublic
    rounds: list[RoundAuditFigure]
    streams: dict[str, AuditFigure]
    gold: list[GoldAgreement] = Field(description="Per reviewer, agreement with gold.")
    method: str
    agreement: dict[str, Any] | None = Field(default=None, description="Two annotators' blind looks at the same "
                                             "samples: 2D (px) and 3D (mm) disagreement per keypoint, per person and "
                                             "overall (services.review.agreement).")
    thresholds: dict[str, Any] | None = Field(default=None, description="The heuristic thresholds in use and why "
                                                                         "(services.review.precision_target).")
    people: dict[str, Any] | None = Field(default=None, description="Per person: accept rate, seconds per sample "
                                          "(annotators), overturned share, gold agreement, seconds per decision "
                                          "(reviewers), in the current week against their earlier weeks and the team "
                                          "median (services.statistics.team_statistics.quality_over_time).")
