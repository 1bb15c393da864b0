"""Human input: submissions (the idempotency unit), keypoint clicks and versioned masks."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import CheckConstraint, ForeignKey, String, UniqueConstraint, false
from sqlalchemy.orm import Mapped, mapped_column

from backend.db.base import Base, utcnow
from backend.models.enums import MaskKind, Visibility, enum_check


class Submission(Base):
    """One annotator submission; `client_id` (client-chosen, unique) makes resubmission a no-op."""

    __tablename__ = "submissions"

    id: Mapped[int] = mapped_column(primary_key=True)
    client_id: Mapped[str] = mapped_column(String(64), unique=True)
    sample_id: Mapped[int] = mapped_column(ForeignKey("samples.id", ondelete="CASCADE"), index=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id"), index=True)
    time_spent_s: Mapped[float]
    n_clicks: Mapped[int]
    n_masks: Mapped[int]
    fit_job_id: Mapped[int | None] = mapped_column(ForeignKey("jobs.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Click(Base):
    """One keypoint in one view, pixels (0, 0 = centre of the top-left pixel)."""

    __tablename__ = "clicks"
    __table_args__ = (
        enum_check("visibility", Visibility),
        CheckConstraint("keypoint >= 0 AND keypoint <= 20", name="keypoint_range"),
        UniqueConstraint("submission_id", "view_id", "keypoint"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    submission_id: Mapped[int] = mapped_column(ForeignKey("submissions.id", ondelete="CASCADE"))
    # The click's sample and user are its submission's (the submission's keys hold them): no foreign keys of
    # their own, which PostgreSQL would check once per click (migration 0008_api_capacity2).
    sample_id: Mapped[int] = mapped_column(index=True)
    view_id: Mapped[int] = mapped_column(ForeignKey("views.id", ondelete="CASCADE"))
    keypoint: Mapped[int]
    x_px: Mapped[float | None]
    y_px: Mapped[float | None]
    visibility: Mapped[str] = mapped_column(String(20))
    # Accepted from a proposal rather than placed by hand (the annotator only looked at it).
    from_proposal: Mapped[bool] = mapped_column(default=False, server_default=false())
    user_id: Mapped[int]
    time_spent_s: Mapped[float]
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Mask(Base):
    """A versioned hand mask of one view: chroma key, HandSegNet prediction, human correction or the
    fitted model's silhouette. The newest version of a view is the one in use."""

    __tablename__ = "masks"
    __table_args__ = (UniqueConstraint("view_id", "version"), enum_check("kind", MaskKind))

    id: Mapped[int] = mapped_column(primary_key=True)
    view_id: Mapped[int] = mapped_column(ForeignKey("views.id", ondelete="CASCADE"), index=True)
    kind: Mapped[str] = mapped_column(String(20))
    version: Mapped[int]
    storage_key: Mapped[str] = mapped_column(String(500))
    model_version: Mapped[str | None] = mapped_column(String(100))
    submission_id: Mapped[int | None] = mapped_column(ForeignKey("submissions.id", ondelete="SET NULL"))
    created_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
