"""Read helpers for samples and their views, shared by the queues' routes."""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import null, select
from sqlalchemy.orm import Session

from backend.models.capture import CameraCalibration, Sample, View
from backend.models.labels import Mask
from backend.services.errors import NotFoundError


@dataclass(frozen=True)
class ViewInfo:
    id: int
    camera: str
    width: int
    height: int
    mask_id: int | None  # newest mask version, if any


def get_sample(session: Session, sample_id: int) -> Sample:
    sample = session.get(Sample, sample_id)
    if sample is None:
        raise NotFoundError(f"sample {sample_id} not found")
    return sample


def views_of(session: Session, sample_id: int, with_masks: bool = True) -> list[ViewInfo]:
    """One statement: the views, their cameras and (correlated subquery on the (view, version) unique index)
    each view's newest mask."""
    newest = (select(Mask.id).where(Mask.view_id == View.id).order_by(Mask.version.desc()).limit(1)
              .correlate(View).scalar_subquery() if with_masks else null())
    rows = session.connection().execute(
        select(View.id, CameraCalibration.name, View.width, View.height, newest)
        .join(CameraCalibration, CameraCalibration.id == View.camera_id)
        .where(View.sample_id == sample_id)
        .order_by(View.id)
    ).all()
    return [ViewInfo(*r) for r in rows]


def get_view(session: Session, view_id: int) -> View:
    view = session.get(View, view_id)
    if view is None:
        raise NotFoundError(f"view {view_id} not found")
    return view


def get_mask(session: Session, mask_id: int) -> Mask:
    mask = session.get(Mask, mask_id)
    if mask is None:
        raise NotFoundError(f"mask {mask_id} not found")
    return mask
