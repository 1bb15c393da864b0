"""Synthetic multi-view hand keypoints with a detector's faults, for the calibration check's tests.

A hand-shaped set of 21 keypoints (FreiHAND order, a slightly curled right hand ~19 cm long) moves over the
frames within `reach_m` of the rig's focus; every camera sees it through its TRUE calibration; the 2D keypoints
then get what a pretrained detector adds: Gaussian noise (`noise_px`, per camera), a fraction of far-off
keypoints (`outlier_fraction`, 30-150 px away) and whole views that found something else (`wrong_view_fraction`:
that view's keypoints are those of a hand 10-25 cm away). Keypoints outside the image are not visible.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.projection import project_points

# Per finger (thumb, index, middle, ring, pinky): its base on the palm (the thumb's CMC, the others' MCP; x, y),
# its direction in the palm's plane and the lengths of its three segments, metres.
_FINGERS = (((0.02, 0.02), (0.6, 0.8), (0.04, 0.032, 0.028)), ((0.03, 0.09), (0.1, 1.0), (0.04, 0.025, 0.02)),
            ((0.008, 0.095), (0.0, 1.0), (0.045, 0.028, 0.022)), ((-0.012, 0.09), (-0.1, 1.0), (0.042, 0.026, 0.02)),
            ((-0.03, 0.08), (-0.2, 1.0), (0.033, 0.02, 0.018)))


def hand_keypoints(curl: float = 0.3) -> np.ndarray:
    """(21, 3) a hand in its own frame (wrist at the origin, fingers along +y, palm normal +z), metres; each
    finger joint bends by `curl` radians towards the palm."""
    points = [np.zeros(3)]
    for base, direction, lengths in _FINGERS:
        along = np.array([*direction, 0.0]) / np.hypot(*direction)
        p = np.array([*base, 0.0])
        points.append(p)
        for j, length in enumerate(lengths):
            bend = curl * (j + 1)
            p = p + length * (along * np.cos(bend) + np.array([0.0, 0.0, -1.0]) * np.sin(bend))
            points.append(p)
    return np.asarray(points)


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def hand_track(rng: np.random.Generator, frames: int = 20, reach_m: float = 0.3,
               focus: np.ndarray | None = None) -> np.ndarray:
    """(frames, 21, 3) world keypoints: the hand turning and moving smoothly within `reach_m` of `focus`."""
    focus = np.zeros(3) if focus is None else focus
    start, end = (rng.normal(size=(2, 3)) * reach_m / 2.5).clip(-reach_m / 1.8, reach_m / 1.8)
    R0, R1 = _rotation(rng), _rotation(rng)
    delta = cv2.Rodrigues(R1 @ R0.T)[0].ravel()
    hand = hand_keypoints(rng.uniform(0.1, 0.6))
    out = []
    for s in np.linspace(0, 1, frames):
        R = cv2.Rodrigues(delta * s * 0.5)[0] @ R0
        out.append(focus + start + (end - start) * s + hand @ R.T)
    return np.asarray(out)


def observe(points: np.ndarray, cameras: list[Camera], rng: np.random.Generator, noise_px: tuple[float, float] =
            (5.0, 15.0), outlier_fraction: float = 0.05, wrong_view_fraction: float = 0.02
            ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The detector-like 2D keypoints of `points` (F, 21, 3) in `cameras` (their true calibration).

    Returns per frame (C, 21, 2) distorted pixels and (C, 21) visibility."""
    C = len(cameras)
    sigma = rng.uniform(*noise_px, C)
    keypoints, visible = [], []
    for frame in points:
        px, depth = project_points(frame, cameras)
        for c in np.flatnonzero(rng.random(C) < wrong_view_fraction):  # this view found another hand
            direction = rng.normal(size=3)
            other = frame + direction / np.linalg.norm(direction) * rng.uniform(0.1, 0.25)
            px[c] = project_points(other, [cameras[c]])[0][0]
        px = px + rng.normal(size=px.shape) * sigma[:, None, None]
        far = rng.random((C, 21)) < outlier_fraction
        angle = rng.uniform(0, 2 * np.pi, (C, 21))
        px[far] += (rng.uniform(30, 150, (C, 21, 1)) * np.stack([np.cos(angle), np.sin(angle)], -1))[far]
        inside = ((px >= 0) & (px <= np.array([[c.width - 1, c.height - 1] for c in cameras])[:, None])).all(-1)
        keypoints.append(px)
        visible.append(inside & (depth > 0))
    return keypoints, visible


def rotated(camera: Camera, degrees: float, axis: np.ndarray) -> Camera:
    """`camera` turned by `degrees` about `axis` (its own frame) through its centre."""
    delta = cv2.Rodrigues(np.deg2rad(degrees) * np.asarray(axis, float).reshape(3, 1) / np.linalg.norm(axis))[0]
    return replace(camera, R=delta @ camera.R, t=delta @ camera.t)


def moved(camera: Camera, shift_world: np.ndarray) -> Camera:
    """`camera` with its centre moved by `shift_world` (world units), the orientation kept."""
    return replace(camera, t=camera.t - camera.R @ np.asarray(shift_world, float))


def swapped(cameras: list[Camera], i: int, j: int) -> list[Camera]:
    """The calibration with cameras i and j's entries exchanged (names kept in place)."""
    out = list(cameras)
    out[i], out[j] = replace(cameras[j], name=cameras[i].name), replace(cameras[i], name=cameras[j].name)
    return out
