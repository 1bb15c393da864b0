"""Mask preparation for the silhouette term: the wrist cut, distance fields and boundary samples.

Chroma-key masks contain the forearm; the hand model stops at the wrist. The paper refines masks "to
co-align the segmentation mask with the hand model's wrist"; we cut automatically at the wrist of the
model (or of the triangulated wrist click), see `cut_forearm`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.projection import undistort_pixels

# Views that look along the forearm within this angle are not cut: their cut would be ill-posed, and the
# forearm then hides behind (or in front of) the hand anyway.
MIN_CUT_ANGLE_DEG = 25.0


@dataclass(frozen=True)
class MaskPixels:
    """A mask's pixels and where they look: what `cut_forearm` needs of a mask whatever the hand's pose, so a fit
    that cuts the same mask twice (a first fit and its continuation) undistorts its pixels once.

    Attributes:
        rows, cols: (N,) int, the mask's pixels (np.nonzero order).
        ideal_px: (N, 2) float64, those pixels (x, y) with the lens distortion removed (same K).
    """

    rows: np.ndarray
    cols: np.ndarray
    ideal_px: np.ndarray


def mask_pixels(mask: np.ndarray, camera: Camera) -> MaskPixels:
    """The (H, W) bool mask's pixels and their undistorted positions in the camera (`MaskPixels`)."""
    rows, cols = np.nonzero(mask)
    return MaskPixels(rows, cols, undistort_pixels(np.stack([cols, rows], 1).astype(np.float64), camera))


def cut_forearm(mask: np.ndarray, camera: Camera, wrist_world: np.ndarray, hand_dir_world: np.ndarray,
                margin_m: float = 0.004, body_radius_m: float = 0.028,
                model_silhouette: np.ndarray | Callable[[], np.ndarray] | None = None, near_model_px: float = 15.0,
                pixels: MaskPixels | None = None) -> np.ndarray:
    """Remove the forearm from a hand+forearm mask.

    Each mask pixel's viewing ray is followed to where it enters a cylinder of `body_radius_m` around
    the arm axis (wrist + s * hand_dir): that entry point approximates the visible surface, and the
    pixel is forearm when it lies beyond the wrist (s < -margin_m). Rays that miss the cylinder use
    their closest approach to the axis instead.

    Args:
        mask: (H, W) bool.
        camera: the view's camera.
        wrist_world: (3,) wrist position, metres, world frame.
        hand_dir_world: (3,) direction from the wrist into the hand (toward the middle finger base).
        margin_m: how far beyond the wrist plane a pixel may lie and still be kept, metres.
        body_radius_m: radius of the cylinder standing in for the wrist and forearm surface, metres
            (tuned on rendered hand and forearm cylinders: 2-3.5 cm keep >= 90 % of the hand and cut
            >= 98 % of the forearm in all eight views of the default rig).
        model_silhouette: (H, W) bool silhouette of the current hand estimate, for degenerate views, or a function
            that renders it: it is called only for such a view (most views need no rendering).
        near_model_px: how far from that silhouette mask pixels are kept, pixels at 320 px width.
        pixels: `mask_pixels(mask, camera)` where the caller has it already; computed here otherwise.
    Returns:
        (H, W) bool, the hand part of the mask.
    """
    d = np.asarray(hand_dir_world, dtype=np.float64)
    d = d / np.linalg.norm(d)
    w = np.asarray(wrist_world, dtype=np.float64)
    center = camera.center_world
    to_wrist = w - center
    angle = np.degrees(np.arccos(min(1.0, abs(float(to_wrist @ d)) / np.linalg.norm(to_wrist))))
    if not mask.any():
        return mask.copy()
    if angle < MIN_CUT_ANGLE_DEG:
        if model_silhouette is None:
            return mask.copy()
        silhouette = model_silhouette() if callable(model_silhouette) else model_silhouette
        radius = max(1, round(near_model_px * camera.width / 320))
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        return mask & cv2.dilate(silhouette.astype(np.uint8), kernel).astype(bool)
    pixels = pixels or mask_pixels(mask, camera)
    v, u, ideal = pixels.rows, pixels.cols, pixels.ideal_px
    rays_cam = np.linalg.solve(camera.K, np.concatenate([ideal, np.ones((len(u), 1))], 1).T)  # (3, N)
    rays = (camera.R.T @ rays_cam).T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)  # (N, 3) unit world directions
    o = center - w  # ray origins relative to the wrist
    # Components perpendicular to the axis: |o_p + a r_p| = R gives the cylinder entry a_in.
    r_p = rays - np.outer(rays @ d, d)
    o_p = o - (o @ d) * d
    qa = np.einsum("ij,ij->i", r_p, r_p)
    qb = 2 * (r_p @ o_p)
    qc = o_p @ o_p - body_radius_m**2
    disc = qb * qb - 4 * qa * qc
    hits = (disc >= 0) & (qa > 1e-12)
    a_in = (-qb - np.sqrt(np.where(hits, disc, 0.0))) / (2 * np.maximum(qa, 1e-12))
    a_closest = -qb / (2 * np.maximum(qa, 1e-12))
    a = np.where(hits, a_in, a_closest)
    s = o @ d + a * (rays @ d)  # axial position of the chosen point
    keep = s >= -margin_m
    out = np.zeros_like(mask)
    out[v[keep], u[keep]] = True
    return out


def outside_distance_px(mask: np.ndarray) -> np.ndarray:
    """(H, W) float32 distance from each pixel to the nearest mask pixel (0 inside), pixels.

    The "model outside the mask" half of the paper's symmetric EDT term (eq. 4). OpenCV's exact
    Euclidean distance transform does the work.
    """
    if not mask.any():
        return np.full(mask.shape, np.float32(max(mask.shape)), dtype=np.float32)
    return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def boundary_points(mask: np.ndarray, count: int, rng: np.random.Generator,
                    exclude: np.ndarray | None = None) -> np.ndarray:
    """(N <= count, 2) pixel positions (x, y) spread evenly along the mask's outer contours.

    `exclude` (H, W) bool drops contour pixels next to it: after a wrist cut, the cut line is not a
    real silhouette edge.
    """
    return boundary_samples(mask, count, rng, exclude)[0]


def boundary_samples(mask: np.ndarray, count: int, rng: np.random.Generator,
                     exclude: np.ndarray | None = None,
                     tangent_span: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Boundary samples as in `boundary_points` and the mask's outward unit normal at each.

    The normal is perpendicular to the contour chord from `tangent_span` contour pixels before the
    sample to as many after it, turned to point out of the mask. Returns (N, 2) positions (x, y) and
    (N, 2) normals.
    """
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    points, normals = [], []
    for contour in contours:
        c = contour.reshape(-1, 2).astype(np.float64)
        chord = np.roll(c, -tangent_span, axis=0) - np.roll(c, tangent_span, axis=0)
        n = np.stack([chord[:, 1], -chord[:, 0]], 1)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        n = np.where(length > 0, n / np.maximum(length, 1e-12), 0.0)
        points.append(c)
        normals.append(n)
    if not points:
        return np.zeros((0, 2)), np.zeros((0, 2))
    points_all, normals_all = np.concatenate(points), np.concatenate(normals)
    # Outward: a step along the normal should leave the mask (sampled 1.5 px away, clamped to the image).
    H, W = mask.shape
    probe = np.rint(points_all + 1.5 * normals_all).astype(int)
    inside = mask[probe[:, 1].clip(0, H - 1), probe[:, 0].clip(0, W - 1)]
    normals_all[inside] *= -1
    keep = np.ones(len(points_all), dtype=bool)
    if exclude is not None and exclude.any():
        near = cv2.dilate(exclude.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        keep = ~near[points_all[:, 1].astype(int), points_all[:, 0].astype(int)]
    points_all, normals_all = points_all[keep], normals_all[keep]
    if len(points_all) <= count:
        return points_all, normals_all
    start = rng.uniform(0, len(points_all) / count)
    pick = (start + np.arange(count) * len(points_all) / count).astype(int) % len(points_all)
    return points_all[pick], normals_all[pick]
