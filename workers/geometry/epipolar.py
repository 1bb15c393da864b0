"""Epipolar geometry of two calibrated cameras: the fundamental matrix and point-to-line distances.

Pixels are undistorted first (`projection.undistort_pixels`), so the pinhole relation x_b^T F x_a = 0 holds.
"""

from __future__ import annotations

import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.projection import undistort_pixels


def fundamental_matrix(a: Camera, b: Camera) -> np.ndarray:
    """(3, 3) F with x_b^T F x_a = 0 for undistorted pixels x_a of camera a and x_b of camera b."""
    R = b.R @ a.R.T
    t = b.t - R @ a.t
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return np.linalg.inv(b.K).T @ tx @ R @ np.linalg.inv(a.K)


def line_distances(F: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """(N,) pixels: distance of each undistorted point xb (N, 2) to the epipolar line F xa of its partner xa (N, 2)."""
    ha, hb = np.c_[xa, np.ones(len(xa))], np.c_[xb, np.ones(len(xb))]
    lines = ha @ F.T
    return np.abs(np.sum(lines * hb, axis=1)) / np.maximum(np.hypot(lines[:, 0], lines[:, 1]), 1e-12)


def symmetric_epipolar_distances(pixels_a: np.ndarray, pixels_b: np.ndarray, a: Camera, b: Camera) -> np.ndarray:
    """(N,) pixels: the mean of each pair's two point-to-epipolar-line distances (xb to F xa, xa to F^T xb).

    Args:
        pixels_a, pixels_b: (N, 2) corresponding distorted pixels of cameras a and b ((0, 0) the top-left pixel's
            centre).
    """
    xa, xb = undistort_pixels(pixels_a, a), undistort_pixels(pixels_b, b)
    F = fundamental_matrix(a, b)
    return 0.5 * (line_distances(F, xa, xb) + line_distances(F.T, xb, xa))
