"""Geometric sanity of a converted rig: every camera must see the point the other cameras look at.

A transposed rotation (camera -> world read as world -> camera), a pose chained to another camera read
as a world pose, or a sign flip moves one camera's optical axis away from the rig's common focus. For
each camera we find the point closest (least squares) to the other cameras' optical axes and require it
in front of that camera and inside its image (with a margin). Rigs whose other axes are (near) parallel
have no such point; the check then says so instead of guessing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.geometry.camera import Camera

MAX_CONDITION = 1e6
IMAGE_MARGIN = 0.5  # the focus may project up to half an image size outside the frame


@dataclass(frozen=True)
class AimResult:
    """How one camera relates to the focus of the others.

    Attributes:
        camera: camera name.
        focus_world: (3,) the point closest to the other cameras' optical axes, metres, or None (no focus).
        depth_m: the focus's depth in this camera (negative: behind it), or None.
        pixel: (2,) the focus projected (pinhole, no distortion), pixels, or None.
        problem: a sentence saying what is wrong, or None.
    """

    camera: str
    focus_world: np.ndarray | None
    depth_m: float | None
    pixel: np.ndarray | None
    problem: str | None


def _axis(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    return cam.center_world, cam.R[2]  # the camera's z axis in world coordinates is R's third row


def common_focus(cameras: list[Camera]) -> np.ndarray | None:
    """(3,) the point closest to all cameras' optical axes (least squares), or None when ill-conditioned."""
    if len(cameras) < 2:
        return None
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in cameras:
        c, d = _axis(cam)
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c
    if np.linalg.cond(A) > MAX_CONDITION:
        return None
    return np.linalg.solve(A, b)


def check_aim(cameras: list[Camera]) -> list[AimResult]:
    """One `AimResult` per camera (leave-one-out focus of the others); needs at least 3 cameras to judge."""
    results = []
    for i, cam in enumerate(cameras):
        others = cameras[:i] + cameras[i + 1:]
        focus = common_focus(others) if len(others) >= 2 else None
        if focus is None:
            results.append(AimResult(cam.name, None, None, None, None))
            continue
        X = cam.R @ focus + cam.t
        depth = float(X[2])
        if depth <= 0:
            results.append(AimResult(cam.name, focus, depth, None,
                                     f"camera {cam.name!r}: the point the other cameras look at is {-depth:.3g} m "
                                     "behind it (R or t inverted: camera -> world read as world -> camera, a "
                                     "transposed R, or a pose relative to another camera?)"))
            continue
        uv = (cam.K @ (X / depth))[:2]
        mx, my = IMAGE_MARGIN * cam.width, IMAGE_MARGIN * cam.height
        inside = -mx <= uv[0] <= cam.width + mx and -my <= uv[1] <= cam.height + my
        problem = None if inside else (
            f"camera {cam.name!r}: the point the other cameras look at projects to ({uv[0]:.0f}, {uv[1]:.0f}) px, "
            f"far outside its {cam.width}x{cam.height} image (a transposed R, or a pose relative to another "
            "camera read as a world pose?)")
        results.append(AimResult(cam.name, focus, depth, uv, problem))
    return results
