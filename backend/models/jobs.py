"""Background jobs (fits, predictions, training, rounds, imports, exports) and their progress."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import CheckConstraint, ForeignKey, String, Text
from sqlalchemy.orm import Mapped, mapped_column

from backend.db.base import Base, utcnow
from backend.models.enums import JobKind, JobState, enum_check


class Job(Base):
    __tablename__ = "jobs"
    __table_args__ = (
        enum_check("kind", JobKind),
        enum_check("state", JobState),
        CheckConstraint("progress >= 0 AND progress <= 1", name="progress_range"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    kind: Mapped[str] = mapped_column(String(20))
    state: Mapped[str] = mapped_column(String(20), default=JobState.queued, index=True)
    progress: Mapped[float] = mapped_column(default=0.0)
    message: Mapped[str] = mapped_column(Text, default="")
    error: Mapped[str | None] = mapped_column(Text)
    sample_id: Mapped[int | None] = mapped_column(ForeignKey("samples.id", ondelete="CASCADE"), index=True)
    round_id: Mapped[int | None] = mapped_column(ForeignKey("rounds.id", ondelete="SET NULL"), index=True)
    payload: Mapped[dict[str, Any]] = mapped_column(default=dict)
    result: Mapped[dict[str, Any] | None]
    created_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)
    # When the current attempt started (services.jobs.jobs.claim): the jobs list's duration runs from here, not
    # from created_at (which includes the wait in the queue).
    started_at: Mapped[datetime | None]
    finished_at: Mapped[datetime | None]
    # Hand-off to the workers (backend.broker.outbox): when the task was sent to the broker (NULL: not
    # yet, or the send failed and the outbox re-sends it), how many times a worker started it, and which one.
    dispatched_at: Mapped[datetime | None]
    attempts: Mapped[int] = mapped_column(default=0, server_default="0")
    worker: Mapped[str | None] = mapped_column(String(200))
    # The operating-system process of the current attempt (backend.broker.worker_processes): a claimant on the same
    # machine takes the job over as soon as that process is gone, without waiting for the heartbeat to age.
    worker_process: Mapped[str | None] = mapped_column(String(120))
