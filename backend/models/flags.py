"""What an annotator said instead of clicking (no hand in a view or the sample, a skip) and the fits that failed
on an annotator's submission: kept out of the fit, counted, and read by the queue so a sample someone passed
on (or whose fit failed on their work) goes to someone else rather than back to them in a loop."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import ForeignKey, Index, String
from sqlalchemy.orm import Mapped, mapped_column

from backend.db.base import Base, utcnow
from backend.models.enums import FlagKind, enum_check


class AnnotationFlag(Base):
    """kind 'no_hand_view' (with `view_id`, written with the submission it came with), 'no_hand' (the whole
    sample: it leaves the queue as rejected), 'skip' (the sample goes to someone else) or 'fit_failed' (the fit
    of `submission_id` failed; `reason` is the fit's error). `user_id`: who said it, or whose submission it was;
    NULL for a fit that failed on no one's submission (pre-annotation)."""

    __tablename__ = "annotation_flags"
    __table_args__ = (enum_check("kind", FlagKind), Index("ix_annotation_flags_sample_user", "sample_id", "user_id"))

    id: Mapped[int] = mapped_column(primary_key=True)
    sample_id: Mapped[int] = mapped_column(ForeignKey("samples.id", ondelete="CASCADE"))
    view_id: Mapped[int | None] = mapped_column(ForeignKey("views.id", ondelete="CASCADE"))
    user_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    submission_id: Mapped[int | None] = mapped_column(ForeignKey("submissions.id", ondelete="CASCADE"))
    kind: Mapped[str] = mapped_column(String(20))
    reason: Mapped[str] = mapped_column(String(2000), default="")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
