"""Label quality (issue 40): blind audits of accepted labels and the admin's quality settings.

Not the audit trail (models/audit.py, every change the server makes): a `LabelAudit` is a second look at one
accepted label by a reviewer who is not told it was accepted, nor by whom (backend/services/review/label_audits.py)."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import CheckConstraint, ForeignKey, Index, String, Text
from sqlalchemy.orm import Mapped, mapped_column

from backend.db.base import Base, utcnow
from backend.models.enums import Stream, enum_check

AUDIT_STATES = ("pending", "done", "void")  # void: the label left the dataset before it was audited
AUDIT_VERDICTS = ("correct", "wrong")
AUDIT_KINDS = ("audit", "gold")  # gold: a gold label slipped into one reviewer's queue (`auditor_id` set at once)


class LabelAudit(Base):
    """One audit of the label a stream accepted (its sample, fit, round and stream as accepted). `verdict`
    'wrong' took the label out of the dataset (its round member deleted) with `reason`; the row keeps where it
    was, so the round's audit figures still count it. The lease is the sample row's (lease_kind 'review')."""

    __tablename__ = "label_audits"
    __table_args__ = (
        enum_check("stream", Stream),
        CheckConstraint(f"state IN ({', '.join(repr(s) for s in AUDIT_STATES)})", name="state_valid"),
        CheckConstraint(f"verdict IS NULL OR verdict IN ({', '.join(repr(v) for v in AUDIT_VERDICTS)})",
                        name="verdict_valid"),
        CheckConstraint(f"kind IN ({', '.join(repr(k) for k in AUDIT_KINDS)})", name="kind_valid"),
        Index("ix_label_audits_state", "state", "id"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    sample_id: Mapped[int] = mapped_column(ForeignKey("samples.id", ondelete="CASCADE"), index=True)
    fit_id: Mapped[int | None] = mapped_column(ForeignKey("fits.id", ondelete="SET NULL"))
    round_id: Mapped[int | None] = mapped_column(ForeignKey("rounds.id", ondelete="SET NULL"), index=True)
    stream: Mapped[str] = mapped_column(String(20))
    kind: Mapped[str] = mapped_column(String(10), default="audit", server_default="audit")
    accepted_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))  # None: heuristic
    state: Mapped[str] = mapped_column(String(20), default="pending")
    verdict: Mapped[str | None] = mapped_column(String(20))
    auditor_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    decision_id: Mapped[int | None] = mapped_column(ForeignKey("decisions.id", ondelete="SET NULL"))
    reason: Mapped[str] = mapped_column(Text, default="")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    decided_at: Mapped[datetime | None]


class QualitySettings(Base):
    """The admin's quality settings: one row (id 1), written on the first change; absent: the defaults."""

    __tablename__ = "quality_settings"
    __table_args__ = (
        CheckConstraint("audit_share >= 0 AND audit_share <= 1", name="audit_share_range"),
        CheckConstraint("precision_target IS NULL OR (precision_target > 0 AND precision_target < 1)",
                        name="precision_target_range"),
        CheckConstraint("auditor_error_rate >= 0 AND auditor_error_rate < 0.5", name="auditor_error_rate_range"),
        CheckConstraint("gold_share >= 0 AND gold_share <= 1", name="gold_share_range"),
        CheckConstraint("agreement_share >= 0 AND agreement_share <= 1", name="agreement_share_range"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    audit_share: Mapped[float] = mapped_column(default=0.05)  # of each stream's accepts, in [0, 1]
    audit_seed: Mapped[int] = mapped_column(default=0)  # which labels the share picks (a hash of it and the ids)
    precision_target: Mapped[float | None] = mapped_column(default=None)  # most auto-accepts wrong, e.g. 0.02
    min_audits_for_target: Mapped[int] = mapped_column(default=30)
    auditor_error_rate: Mapped[float] = mapped_column(default=0.0)  # an auditor's verdict wrong, in [0, 0.5)
    gold_share: Mapped[float] = mapped_column(default=0.0)  # of a reviewer's tasks, gold labels (in [0, 1])
    # of annotated samples, annotated twice (services.review.agreement); rows from before the setting: 0 (off)
    agreement_share: Mapped[float] = mapped_column(default=0.05, server_default="0")
    updated_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)


class GoldLabel(Base):
    """An accepted label an admin marked gold (known right): slipped unmarked into reviewers' queues, each
    reviewer's agreement with it measured (services.review.label_audits; a `LabelAudit` of kind 'gold' per look)."""

    __tablename__ = "gold_labels"

    id: Mapped[int] = mapped_column(primary_key=True)
    sample_id: Mapped[int] = mapped_column(ForeignKey("samples.id", ondelete="CASCADE"), unique=True)
    fit_id: Mapped[int | None] = mapped_column(ForeignKey("fits.id", ondelete="SET NULL"))
    stream: Mapped[str] = mapped_column(String(20))
    marked_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
