"""What a capture is made of: projects, cameras, subjects, sequences, samples (frames) and views."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import ForeignKey, Index, String, UniqueConstraint
from sqlalchemy.orm import Mapped, mapped_column, relationship

from backend.db.base import Base, utcnow
from backend.models.enums import HandSide, SampleState, Split, enum_check


class Project(Base):
    __tablename__ = "projects"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    description: Mapped[str] = mapped_column(String(2000), default="")
    hand_model: Mapped[str] = mapped_column(String(200), default="")
    synthetic: Mapped[bool] = mapped_column(default=False)
    # capture.json's working_width_px: views wider than it are shown (and served) at this width, derived
    # from the full-resolution originals in storage; None: as they are.
    working_width_px: Mapped[int | None] = mapped_column(default=None)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class CameraCalibration(Base):
    """One calibrated camera of a project's rig (workers.geometry.camera.Camera as a row)."""

    __tablename__ = "camera_calibrations"
    __table_args__ = (UniqueConstraint("project_id", "name"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    project_id: Mapped[int] = mapped_column(ForeignKey("projects.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(100))
    width: Mapped[int]
    height: Mapped[int]
    K: Mapped[list[Any]]
    dist: Mapped[list[Any]]
    R: Mapped[list[Any]]
    t: Mapped[list[Any]]


class Subject(Base):
    __tablename__ = "subjects"
    __table_args__ = (UniqueConstraint("project_id", "external_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    project_id: Mapped[int] = mapped_column(ForeignKey("projects.id", ondelete="CASCADE"), index=True)
    external_id: Mapped[str] = mapped_column(String(100))


class Sequence(Base):
    __tablename__ = "sequences"
    __table_args__ = (UniqueConstraint("project_id", "external_id"), enum_check("split", Split),
                      enum_check("side", HandSide))

    id: Mapped[int] = mapped_column(primary_key=True)
    project_id: Mapped[int] = mapped_column(ForeignKey("projects.id", ondelete="CASCADE"), index=True)
    subject_id: Mapped[int | None] = mapped_column(ForeignKey("subjects.id", ondelete="SET NULL"))
    external_id: Mapped[str] = mapped_column(String(100))
    split: Mapped[str] = mapped_column(String(20))
    green_screen: Mapped[bool] = mapped_column(default=True)
    fps: Mapped[float] = mapped_column(default=0.0)
    holds_object: Mapped[bool] = mapped_column(default=False)
    # Which hand: the fit loads this side's model; rows from before the column are right hands.
    side: Mapped[str] = mapped_column(String(10), default=HandSide.right.value, server_default=HandSide.right.value)


class Sample(Base):
    """One synchronized multi-view frame: the unit that is annotated, fitted and verified.

    The lease columns implement the queues: a sample is held by at most one user at a time because the
    lease lives in the sample's own row and is taken by one atomic update (see services.leases.queues).
    """

    __tablename__ = "samples"
    __table_args__ = (
        UniqueConstraint("sequence_id", "frame_index"),
        enum_check("state", SampleState),
        enum_check("split", Split),
        Index("ix_samples_queue", "state", "id"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    sequence_id: Mapped[int] = mapped_column(ForeignKey("sequences.id", ondelete="CASCADE"), index=True)
    frame_index: Mapped[int]
    time_s: Mapped[float]
    split: Mapped[str] = mapped_column(String(20))
    green_screen: Mapped[bool]
    ground_truth_key: Mapped[str | None] = mapped_column(String(500))
    state: Mapped[str] = mapped_column(String(20), default=SampleState.unlabeled)
    # Denormalised from the latest prediction / fit, for the queues' ordering and policy.
    confidence: Mapped[float | None]
    pose_distance: Mapped[float | None]
    # Plain column, not a foreign key: fits reference samples, and a cycle would need ALTER on SQLite.
    current_fit_id: Mapped[int | None]
    leased_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), index=True)
    lease_kind: Mapped[str | None] = mapped_column(String(20))
    lease_token: Mapped[str | None] = mapped_column(String(64))
    lease_expires_at: Mapped[datetime | None]
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)

    views: Mapped[list[View]] = relationship(back_populates="sample", order_by="View.id", lazy="raise")


# The review queue in its order (backend/db/statements/lease_statement.py: queue_order), so a reviewer's lease reads
# its head instead of sorting every sample in review (20,000 in review: 5-9 ms a lease, EXPLAIN ANALYZE). PostgreSQL
# only: SQLite refuses NULLS LAST in an index, and an embedded project's review queue is small.
Index("ix_samples_review_queue", Sample.state, Sample.confidence.desc().nulls_last(), Sample.id).ddl_if(
    dialect="postgresql")


class View(Base):
    """One camera's image of a sample."""

    __tablename__ = "views"
    __table_args__ = (UniqueConstraint("sample_id", "camera_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    sample_id: Mapped[int] = mapped_column(ForeignKey("samples.id", ondelete="CASCADE"), index=True)
    camera_id: Mapped[int] = mapped_column(ForeignKey("camera_calibrations.id", ondelete="CASCADE"))
    image_key: Mapped[str] = mapped_column(String(500))
    width: Mapped[int]
    height: Mapped[int]

    sample: Mapped[Sample] = relationship(back_populates="views", lazy="raise")
