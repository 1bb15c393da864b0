"""Two-view epipolar fits for the calibration check (workers/rigs/check.py); F and the distances themselves are
workers/geometry/epipolar.py's.

All pixels here are undistorted ("ideal") pixels of each camera's own K; x_b^T F x_a = 0 for a point seen as x_a by
camera a and x_b by camera b. Distances are signed symmetric epipolar distances: the mean of x_b's distance to the
line F x_a and x_a's distance to the line F^T x_b, pixels.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.epipolar import fundamental_from_poses, signed_symmetric_distances
from workers.geometry.rotation import axis_angle_to_matrix

# Robust weights (Cauchy) use this multiple of the residuals' robust spread (1.4826 MAD) as their scale.
CAUCHY_SCALE = 2.4
TRIM_KEEP = 0.8  # the figures judged leave out the largest 20 % of distances (detector outliers, wrong views)


def stacked_distances(Fs: np.ndarray, which: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """`distances` of many pairs at once: Fs (P, 3, 3), which (N,) the pair of each of the N correspondences."""
    F = Fs[which]
    line_b = np.einsum("nij,nj->ni", F[:, :, :2], xa) + F[:, :, 2]
    line_a = np.einsum("nji,nj->ni", F[:, :2, :], xb) + F[:, 2, :]
    e = line_b[:, 0] * xb[:, 0] + line_b[:, 1] * xb[:, 1] + line_b[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return 0.5 * e * (1 / np.hypot(line_b[:, 0], line_b[:, 1]) + 1 / np.hypot(line_a[:, 0], line_a[:, 1]))


def robust_spread(d: np.ndarray) -> float:
    """1.4826 x the median absolute value: the standard deviation of Gaussian residuals, unmoved by outliers."""
    return float(1.4826 * np.median(np.abs(d))) if d.size else 0.0


def trimmed_rms(d: np.ndarray) -> float:
    """Root mean square of the smallest TRIM_KEEP of |d|: the spread of the bulk, outliers left out (pixels)."""
    if not d.size:
        return float("nan")
    keep = np.sort(np.asarray(d, np.float64) ** 2)[:max(1, int(np.ceil(TRIM_KEEP * d.size)))]
    return float(np.sqrt(keep.mean()))


def _robust_cost(d: np.ndarray, scale: float) -> float:
    return float(np.sum(np.log1p((d / scale) ** 2)))


def robust_fit(residuals: Callable[[np.ndarray], np.ndarray], n_params: int, iterations: int = 8
               ) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt on a Cauchy loss from parameters 0 (the calibration as it is), forward-difference
    Jacobian; the loss scale is the starting residuals' robust spread. Returns the parameters and the residuals
    there; it never ends worse than it started."""
    p = np.zeros(n_params)
    d = residuals(p)
    scale = max(CAUCHY_SCALE * robust_spread(d), 1e-9)
    cost, damping, h = _robust_cost(d, scale), 1e-3, 1e-6
    for _ in range(iterations):
        J = np.stack([(residuals(p + h * e) - d) / h for e in np.eye(n_params)], axis=1)
        w = 1 / (1 + (d / scale) ** 2)
        A, g = J.T @ (J * w[:, None]), J.T @ (w * d)
        improved = False
        for _ in range(4):
            p_new = p - np.linalg.solve(A + damping * np.diag(np.diag(A) + 1e-12), g)
            d_new = residuals(p_new)
            new_cost = _robust_cost(d_new, scale)
            if new_cost < cost:
                improved = cost - new_cost > 1e-6 * cost
                p, d, cost, damping = p_new, d_new, new_cost, damping / 10
                break
            damping *= 10
        if not improved:
            break
    return p, d


def refit_pair(a: Camera, b: Camera, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """The distances (N,) of xa, xb (N, 2) under the best relative pose of the two cameras near the calibrated
    one (intrinsics kept): about what any extrinsic calibration could achieve on these keypoints, the yardstick
    the calibration's own distances are judged by. Starts from the calibration, so no random sampling is
    needed and it never ends worse."""
    Ka, Kb_t = np.linalg.inv(a.K), np.linalg.inv(b.K).T
    R = b.R @ a.R.T
    t = b.t - R @ a.t
    t = t / max(float(np.linalg.norm(t)), 1e-12)
    tangent = np.linalg.svd(t[None])[2][1:]  # (2, 3) orthonormal, perpendicular to the baseline

    def residuals(p: np.ndarray) -> np.ndarray:
        """5 parameters: a rotation vector, and the baseline direction moved in its tangent plane."""
        moved = t + p[3:] @ tangent
        moved = moved / np.linalg.norm(moved)
        tx = np.array([[0, -moved[2], moved[1]], [moved[2], 0, -moved[0]], [-moved[1], moved[0], 0]])
        return signed_symmetric_distances(Kb_t @ tx @ axis_angle_to_matrix(p[:3]) @ R @ Ka, xa, xb)

    if len(xa) < 8:
        return residuals(np.zeros(5))
    return robust_fit(residuals, 5)[1]


def corrected(camera: Camera, params: np.ndarray, kind: str) -> Camera:
    """`camera` with a pose correction: "rotation" (3: a rotation vector in the camera's frame, about its centre,
    radians), "translation" (3: its centre moved, world units) or "pose" (6: both)."""
    rvec = params[:3] if kind in ("rotation", "pose") else np.zeros(3)
    shift = params[3:] if kind == "pose" else params if kind == "translation" else np.zeros(3)
    R = axis_angle_to_matrix(rvec) @ camera.R
    center = camera.center_world + shift
    return replace(camera, R=R, t=-R @ center)


def fit_correction(camera: Camera, partners: Sequence[Camera], x_self: Sequence[np.ndarray],
                   x_partner: Sequence[np.ndarray], kind: str) -> tuple[np.ndarray, list[np.ndarray]]:
    """The pose correction of `camera` (see `corrected`) that best explains its pairs with `partners`.

    Args:
        x_self, x_partner: per partner (N_p, 2) undistorted pixels of the same keypoints in `camera` and in it.
    Returns:
        the parameters (3 or 6), and per partner the (N_p,) signed distances after the correction.
    """
    sizes = np.cumsum([len(x) for x in x_self])[:-1]
    n_params = 6 if kind == "pose" else 3
    K_inv, center = np.linalg.inv(camera.K), camera.center_world
    others = [(np.linalg.inv(p.K), p.R, p.t) for p in partners]
    x_a = np.concatenate(list(x_self))
    x_b = np.concatenate(list(x_partner))
    which = np.repeat(np.arange(len(others)), [len(x) for x in x_self])

    def residuals(params: np.ndarray) -> np.ndarray:
        rvec = params[:3] if kind in ("rotation", "pose") else np.zeros(3)
        shift = params[3:] if kind == "pose" else params if kind == "translation" else np.zeros(3)
        R = axis_angle_to_matrix(rvec) @ camera.R
        t = -R @ (center + shift)
        Fs = np.stack([fundamental_from_poses(K_inv, R, t, *other) for other in others])
        return stacked_distances(Fs, which, x_a, x_b)

    params, d = robust_fit(residuals, n_params)
    return params, np.split(d, sizes)
