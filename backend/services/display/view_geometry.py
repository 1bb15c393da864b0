"""World points into the views of a sample, for the UI's payloads (numpy + OpenCV, no torch;
workers/geometry/projection.py is the torch side).

The conventions are docs/conventions.md's: OpenCV pinhole with (k1, k2, p1, p2, k3), X_c = R X_w + t,
pixel (0, 0) the centre of the top-left pixel; `cv2.projectPoints` is the reference the workers'
projection is tested against, so it is used here directly.
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


def project(points_world: np.ndarray, camera: ViewCamera) -> np.ndarray:
    """(N, 3) metres -> (N, 2) pixels; NaN for points behind the camera (or not finite)."""
    import cv2  # deferred: cv2 out of the API's start-up; only the overlay routes project

    points = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    out = np.full((len(points), 2), np.nan)
    depth = points @ camera.R[2] + camera.t[2]
    ok = np.isfinite(points).all(axis=1) & (depth > 1e-6)
    if ok.any():
        rvec, _ = cv2.Rodrigues(camera.R)
        pixels, _ = cv2.projectPoints(points[ok], rvec, camera.t, camera.K, camera.dist)
        out[ok] = pixels.reshape(-1, 2)
    return out


def pixels_or_none(pixels: np.ndarray, decimals: int = 2) -> list[list[float] | None]:
    """(N, 2) pixels as JSON rows, None where not finite."""
    return [None if not np.isfinite(p).all() else [round(float(p[0]), decimals), round(float(p[1]), decimals)]
            for p in pixels]
