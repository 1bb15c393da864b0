"""Epipolar geometry of two calibrated cameras: the fundamental matrix and point-to-line distances.

Pixels are undistorted first (`projection.undistort_pixels`), so the pinhole relation x_b^T F x_a = 0 holds.
"""

from __future__ import annotations

import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.projection import undistort_pixels


def fundamental_from_poses(Ka_inv: np.ndarray, Ra: np.ndarray, ta: np.ndarray, Kb_inv: np.ndarray, Rb: np.ndarray,
                           tb: np.ndarray) -> np.ndarray:
    """(3, 3) F of two cameras given by inverse intrinsics and world -> camera poses (R (3, 3), t (3,))."""
    R = Rb @ Ra.T
    t = tb - R @ ta
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return Kb_inv.T @ tx @ R @ Ka_inv


def fundamental_matrix(a: Camera, b: Camera) -> np.ndarray:
    """(3, 3) F with x_b^T F x_a = 0 for undistorted pixels x_a of camera a and x_b of camera b."""
    return fundamental_from_poses(np.linalg.inv(a.K), a.R, a.t, np.linalg.inv(b.K), b.R, b.t)


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


def signed_symmetric_distances(F: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """(N,) signed symmetric epipolar distance, pixels, of N correspondences of undistorted pixels xa, xb (N, 2):
    the mean of xb's signed distance to the line F xa and xa's to F^T xb (the sign keeps a systematic shift visible
    to a fit; its absolute value is `symmetric_epipolar_distances`')."""
    line_b = xa @ F[:, :2].T + F[:, 2]  # the lines in b of xa, (N, 3)
    line_a = xb @ F[:2, :] + F[2, :]  # the lines in a of xb
    e = line_b[:, 0] * xb[:, 0] + line_b[:, 1] * xb[:, 1] + line_b[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return 0.5 * e * (1 / np.hypot(line_b[:, 0], line_b[:, 1]) + 1 / np.hypot(line_a[:, 0], line_a[:, 1]))
