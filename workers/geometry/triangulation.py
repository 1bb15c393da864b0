"""Multi-view triangulation: confidence-weighted DLT with pairwise-hypothesis outlier rejection.

Written here rather than taken from OpenCV because cv2.triangulatePoints handles two views only and
has neither weights nor outlier rejection. Pixels are undistorted with OpenCV first.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.projection import project_points, undistort_pixels


@dataclass(frozen=True)
class Triangulation:
    """Result for N points seen by C cameras.

    Attributes:
        points_world: (N, 3) metres; NaN where fewer than two views were usable.
        inliers: (C, N) bool, the views used for each point.
        reprojection_px: (N,) mean reprojection error over the inlier views, pixels (NaN if invalid).
        valid: (N,) bool.
        median_reprojection_px: (N,) median reprojection error over the inlier views, pixels (NaN if invalid).
    """

    points_world: np.ndarray
    inliers: np.ndarray
    reprojection_px: np.ndarray
    valid: np.ndarray
    median_reprojection_px: np.ndarray | None = None


def dlt_homogeneous(P: np.ndarray, uv: np.ndarray, w: np.ndarray) -> np.ndarray:
    """P (..., C, 3, 4), undistorted image points uv (..., C, 2) of those projections (pixels with P = K [R | t],
    normalised with P = [R | t]), weights w (..., C) -> (..., 4) homogeneous world points by weighted DLT,
    one per leading index (batched: numpy's SVD of a stack equals its SVDs one by one)."""
    rows = np.concatenate([
        uv[..., 0:1] * P[..., 2, :] - P[..., 0, :],
        uv[..., 1:2] * P[..., 2, :] - P[..., 1, :],
    ], axis=-2)  # (..., 2C, 4)
    # Normalise each row so a view's weight is not scaled by its focal length or depth.
    rows /= np.linalg.norm(rows[..., :3], axis=-1, keepdims=True) + 1e-12
    rows *= np.concatenate([w, w], axis=-1)[..., None]
    _, _, vt = np.linalg.svd(rows)
    return vt[..., -1, :]


def _dlt_point(P: np.ndarray, uv: np.ndarray, w: np.ndarray) -> np.ndarray:
    """`dlt_homogeneous` dehomogenised: (..., 3) world points, metres."""
    X = dlt_homogeneous(P, uv, w)
    return X[..., :3] / X[..., 3:4]


def _pair_hypothesis_errors(P: np.ndarray, ideal: np.ndarray, observed: np.ndarray, cameras: list[Camera],
                            pixels: np.ndarray) -> list[np.ndarray]:
    """The reprojection errors of every point's two-view hypotheses (a DLT from each pair of its observed views), all
    points in one batch (point by point this was most of a frame's lifting time). P (C, 3, 4); ideal and pixels
    (C, N, 2); observed (C, N) bool. Returns per point n the errors (H_n, C) of its H_n pairs (in
    itertools.combinations order) in every view, inf where unobserved or behind a camera."""
    C, N = observed.shape
    pairs = [np.asarray(list(combinations(np.flatnonzero(observed[:, n]), 2)), dtype=np.int64).reshape(-1, 2)
             for n in range(N)]
    point = np.repeat(np.arange(N), [len(p) for p in pairs])  # (T,) the point of each hypothesis
    if not len(point):
        return [np.zeros((0, C)) for _ in range(N)]
    views = np.concatenate(pairs)  # (T, 2)
    hypotheses = _dlt_point(P[views], ideal[views, point[:, None]], np.ones(views.shape))  # (T, 3)
    errors = _reprojection_errors(hypotheses, cameras, pixels[:, point])
    return np.split(errors, np.cumsum([len(p) for p in pairs])[:-1])


def triangulate(pixels: np.ndarray, cameras: list[Camera], weights: np.ndarray | None = None,
                outlier_px: float = 8.0, refine: bool = False) -> Triangulation:
    """Triangulate N points from C views, rejecting views that disagree with the consensus.

    Args:
        pixels: (C, N, 2) distorted pixel coordinates; NaN where not observed.
        cameras: the C cameras.
        weights: (C, N) confidence in [0, inf); 0 or NaN pixel = not observed. Defaults to 1.
        outlier_px: reprojection error above which a view is an outlier for that point.
        refine: after the DLT, minimise the weighted squared reprojection error over the inliers (Gauss-Newton on
            undistorted pixels), then take as inliers every observed view within `outlier_px` of the refined point
            and refine once more (DLT minimises an algebraic error, not pixels; and a view the best pair missed may
            agree with the consensus).
    Returns:
        Triangulation. Each point first takes the two-view hypothesis with the most inliers (ties by
        lower mean error), then is re-solved by weighted DLT over its inliers. With no hypothesis
        agreed by two views, all observed views are used.
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    C = len(cameras)
    if pixels.ndim != 3 or pixels.shape[0] != C or pixels.shape[2] != 2:
        raise ValueError(f"pixels must have shape (C={C}, N, 2), got {pixels.shape}")
    N = pixels.shape[1]
    w = np.ones((C, N)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (C, N):
        raise ValueError(f"weights must have shape ({C}, {N}), got {w.shape}")
    if np.any(w < 0) or np.any(np.isinf(w)):
        raise ValueError("weights must be finite and non-negative")
    observed = np.isfinite(pixels).all(axis=2) & (np.nan_to_num(w) > 0)
    ideal = np.full_like(pixels, np.nan)
    for c, cam in enumerate(cameras):
        if observed[c].any():
            ideal[c, observed[c]] = undistort_pixels(pixels[c, observed[c]], cam)
    P = np.stack([cam.P for cam in cameras])

    points = np.full((N, 3), np.nan)
    inliers = np.zeros((C, N), dtype=bool)
    error = np.full(N, np.nan)
    median = np.full(N, np.nan)
    hypothesis_errors = _pair_hypothesis_errors(P, ideal, observed, cameras, pixels)
    for n in range(N):
        if observed[:, n].sum() < 2:
            continue
        err = hypothesis_errors[n]  # (H, C), one row per two-view hypothesis
        inl_h = observed[None, :, n] & (err < outlier_px)
        count = inl_h.sum(axis=1)
        mean_err = np.where(inl_h, err, 0).sum(axis=1) / np.maximum(count, 1)
        best = np.lexsort((mean_err, -count))[0]
        inl = inl_h[best] if count[best] >= 2 else observed[:, n]
        X = _dlt_point(P[inl], ideal[inl, n], w[inl, n])
        err = _reprojection_errors(X[None], cameras, pixels[:, n])[0]
        if refine:
            X = refine_point(X, P[inl], ideal[inl, n], w[inl, n])
            err = _reprojection_errors(X[None], cameras, pixels[:, n])[0]
            grown = observed[:, n] & (err < outlier_px)
            if grown.sum() >= 2 and not np.array_equal(grown, inl):
                inl = grown
                X = refine_point(_dlt_point(P[inl], ideal[inl, n], w[inl, n]), P[inl], ideal[inl, n], w[inl, n])
                err = _reprojection_errors(X[None], cameras, pixels[:, n])[0]
        points[n], inliers[:, n], error[n], median[n] = X, inl, float(np.mean(err[inl])), float(np.median(err[inl]))
    return Triangulation(points, inliers, error, np.isfinite(points).all(axis=1), median)


def refine_point(X: np.ndarray, P: np.ndarray, uv: np.ndarray, w: np.ndarray, iterations: int = 5) -> np.ndarray:
    """Gauss-Newton on sum_c w_c |pi(P_c X) - uv_c|^2: X (3,) metres, P (C, 3, 4), undistorted uv (C, 2), w (C,).

    Returns the refined (3,) point, or X itself where a step would put it behind a camera or the system is singular.
    """
    X = np.asarray(X, dtype=np.float64).copy()
    sw = np.sqrt(np.maximum(w, 0.0))
    for _ in range(iterations):
        h = P[:, :, :3] @ X + P[:, :, 3]  # (C, 3) homogeneous image points
        if np.any(h[:, 2] <= 0):
            return X  # the DLT point itself is behind a camera: nothing to refine from
        proj = h[:, :2] / h[:, 2:3]
        # d(proj)/dX = (P[:2, :3] - proj P[2, :3]) / h_z
        J = (P[:, :2, :3] - proj[:, :, None] * P[:, 2:3, :3]) / h[:, 2, None, None]  # (C, 2, 3)
        r = (proj - uv) * sw[:, None]
        Jw = (J * sw[:, None, None]).reshape(-1, 3)
        try:
            step = np.linalg.lstsq(Jw, -r.reshape(-1), rcond=None)[0]
        except np.linalg.LinAlgError:
            return X
        candidate = X + step
        if np.any(P[:, 2, :3] @ candidate + P[:, 2, 3] <= 0) or not np.all(np.isfinite(candidate)):
            return X
        X = candidate
        if np.linalg.norm(step) < 1e-9:
            break
    return X


def _reprojection_errors(X: np.ndarray, cameras: list[Camera], observed_px: np.ndarray) -> np.ndarray:
    """Points (H, 3), observed pixels (C, 2), or (C, H, 2) one set per point (NaN allowed) -> (H, C) pixel errors
    (inf where unobserved or behind the camera)."""
    projected, depth = project_points(X, cameras)  # (C, H, 2), (C, H)
    observed = observed_px[:, None, :] if observed_px.ndim == 2 else observed_px
    err = np.linalg.norm(projected - observed, axis=2).T
    err[~np.isfinite(err) | (depth.T <= 0)] = np.inf
    return err
