"""The cameras of a sample's views, for the UI's payloads; the projection itself is the one of
workers/geometry/projection.py (`project_visible`, numpy, torch-free), conventions docs/conventions.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.capture import CameraCalibration, View
from workers.geometry.camera import Camera


@dataclass(frozen=True, eq=False)
class ViewCamera(Camera):
    """A sample's view with its camera (workers.geometry.camera.Camera: K (3, 3) px, dist (5,), R (3, 3) world
    -> camera, t (3,) metres) and the view's id."""

    view_id: int = 0

    def to_public(self) -> dict:
        return {"view_id": self.view_id, "camera": self.name, "width": self.width, "height": self.height,
                "K": self.K.tolist(), "dist": self.dist.tolist(), "R": self.R.tolist(), "t": self.t.tolist()}


def view_cameras(session: Session, sample_id: int) -> list[ViewCamera]:
    """The sample's views in view-id order (the order every payload uses), with calibrations."""
    rows = session.execute(
        select(View.id, CameraCalibration.name, View.width, View.height, CameraCalibration.K,
               CameraCalibration.dist, CameraCalibration.R, CameraCalibration.t)
        .join(CameraCalibration, CameraCalibration.id == View.camera_id)
        .where(View.sample_id == sample_id).order_by(View.id)
    ).all()
    return [ViewCamera(r[1], r[2], r[3], *(np.asarray(a, dtype=np.float64) for a in r[4:]), view_id=r[0]) for r in rows]


def pixels_or_none(pixels: np.ndarray, decimals: int = 2) -> list[list[float] | None]:
    """(N, 2) pixels as JSON rows, None where not finite."""
    return [None if not np.isfinite(p).all() else [round(float(p[0]), decimals), round(float(p[1]), decimals)]
            for p in pixels]
