"""Machine output: MVNet/HandSegNet predictions and hand-model fits."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import ForeignKey, LargeBinary, String, UniqueConstraint
from sqlalchemy.orm import Mapped, mapped_column

from backend.db.base import Base, utcnow


class Prediction(Base):
    """MVNet's 3D keypoints with confidences (and HandSegNet's masks, stored as Mask rows)."""

    __tablename__ = "predictions"
    # A redelivered prediction task must not record a sample twice.
    __table_args__ = (UniqueConstraint("job_id", "sample_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    sample_id: Mapped[int] = mapped_column(ForeignKey("samples.id", ondelete="CASCADE"), index=True)
    round_id: Mapped[int | None] = mapped_column(ForeignKey("rounds.id", ondelete="SET NULL"))
    job_id: Mapped[int | None] = mapped_column(ForeignKey("jobs.id", ondelete="SET NULL"))
    mvnet_version: Mapped[str] = mapped_column(String(100))
    handsegnet_version: Mapped[str | None] = mapped_column(String(100))
    keypoints_m: Mapped[list[Any]]  # (21, 3) world frame, metres
    confidences: Mapped[list[Any]]  # (21,) in [0, 1]
    mean_confidence: Mapped[float]
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Fit(Base):
    """A hand-model fit: theta (61), its 21 keypoints, diagnostics, and what it was fitted from."""

    __tablename__ = "fits"

    id: Mapped[int] = mapped_column(primary_key=True)
    sample_id: Mapped[int] = mapped_column(ForeignKey("samples.id", ondelete="CASCADE"), index=True)
    round_id: Mapped[int | None] = mapped_column(ForeignKey("rounds.id", ondelete="SET NULL"))
    # Unique: one fit per fit job, however often its task is delivered (NULLs are distinct).
    job_id: Mapped[int | None] = mapped_column(ForeignKey("jobs.id", ondelete="SET NULL"), unique=True)
    prediction_id: Mapped[int | None] = mapped_column(ForeignKey("predictions.id", ondelete="SET NULL"))
    params: Mapped[list[Any]]  # (61,) shape 10, articulation 45, global rotation 3, translation 3 (m)
    keypoints_m: Mapped[list[Any]]  # (21, 3) world frame, metres
    view_ious: Mapped[dict[str, Any]]  # view id -> IoU(predicted mask, model mask)
    diagnostics: Mapped[dict[str, Any]]
    inputs: Mapped[dict[str, Any]]  # e.g. {"submission_ids": [...], "prediction_id": 3, "mask_ids": [...]}
    model_file: Mapped[str] = mapped_column(String(500))
    pose_distance: Mapped[float]  # Euclidean norm of the articulation from the flat hand
    # The fitted mesh, little-endian float32 (V, 3), metres, world frame, as the worker posed it (None for fits
    # recorded before revision 0012); loaded only when read (about 9 kB a fit).
    vertices_f32: Mapped[bytes | None] = mapped_column(LargeBinary, deferred=True)
    heuristic: Mapped[dict[str, Any] | None]
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    @property
    def from_annotation(self) -> bool:
        """The fit used annotators' clicks (D^l when accepted), not only predictions."""
        return bool((self.inputs or {}).get("submission_ids"))
