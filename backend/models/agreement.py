"""Agreement (issue 40): a sample annotated twice, blind, by two different annotators, and how far apart they were.

One row per picked sample (services.review.agreement): the first look's submission and fit, then the second's, the
disagreement figures and which fit became the sample's label."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import CheckConstraint, ForeignKey, String
from sqlalchemy.orm import Mapped, mapped_column

from backend.db.base import Base, utcnow

# second_look: waiting for another annotator's blind look; single: picked, but annotated once (no other active
# annotator to take the second look): the first look's fit is the label, reviewed as usual.
AGREEMENT_STATES = ("second_look", "done", "single")


class AgreementPair(Base):
    """Two annotators' looks at one sample. `disagreement_px`: (21,) per keypoint the mean over views of the 2D
    distance between the two people's clicks, pixels (null where no view has both placed); `mean_px` their mean;
    `disagreement_mm`: mean keypoint distance between the two fits, millimetres, world frame. `label_fit_id`: the
    fit that became the sample's label; `disputed`: the fits were further apart than the threshold."""

    __tablename__ = "agreement_pairs"
    __table_args__ = (
        CheckConstraint(f"state IN ({', '.join(repr(s) for s in AGREEMENT_STATES)})", name="state_valid"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    sample_id: Mapped[int] = mapped_column(ForeignKey("samples.id", ondelete="CASCADE"), unique=True)
    state: Mapped[str] = mapped_column(String(20), default="second_look")
    first_user_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    first_submission_id: Mapped[int | None] = mapped_column(ForeignKey("submissions.id", ondelete="SET NULL"))
    first_fit_id: Mapped[int | None] = mapped_column(ForeignKey("fits.id", ondelete="SET NULL"))
    second_user_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    second_submission_id: Mapped[int | None] = mapped_column(ForeignKey("submissions.id", ondelete="SET NULL"))
    second_fit_id: Mapped[int | None] = mapped_column(ForeignKey("fits.id", ondelete="SET NULL"))
    disagreement_px: Mapped[list[Any] | None]
    mean_px: Mapped[float | None]
    disagreement_mm: Mapped[float | None]
    label_fit_id: Mapped[int | None] = mapped_column(ForeignKey("fits.id", ondelete="SET NULL"))
    disputed: Mapped[bool] = mapped_column(default=False)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    decided_at: Mapped[datetime | None]
