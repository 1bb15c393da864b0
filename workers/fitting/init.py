"""Initialisation without a manual pose: triangulate the clicks, then place and orient the hand.

The model's keypoints (for a few candidate articulations) are rigidly aligned (Kabsch, no scale) to
the triangulated clicks or given 3D keypoints; candidates are ranked by their residual (the engine
refines several of them and keeps the one that fits best).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from workers.fitting.inputs import FrameObservations
from workers.geometry.camera import Camera
from workers.geometry.triangulation import triangulate


@dataclass(frozen=True)
class Placement:
    """Initial global pose for one frame.

    Attributes:
        candidate: index of the chosen candidate articulation.
        global_orient: (3,) axis-angle about the wrist joint.
        transl: (3,) metres.
        targets_m: (21, 3) 3D points the placement was aligned to (NaN where unknown).
        residual_m: RMS distance after alignment, metres.
    """

    candidate: int
    global_orient: np.ndarray
    transl: np.ndarray
    targets_m: np.ndarray
    residual_m: float


def observed_points_3d(obs: FrameObservations, cameras: list[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """(21, 3) 3D keypoints to initialise from and (21,) weights: given 3D keypoints where present,
    otherwise clicks triangulated from two or more views."""
    targets = np.full((21, 3), np.nan)
    weights = np.zeros(21)
    if obs.keypoints_3d is not None:
        kp = np.asarray(obs.keypoints_3d, dtype=np.float64)
        w = np.ones(21) if obs.keypoint_3d_weights is None else np.asarray(obs.keypoint_3d_weights, float)
        ok = np.isfinite(kp).all(1) & (w > 0)
        targets[ok], weights[ok] = kp[ok], w[ok]
    # Only the keypoints without a 3D one are triangulated (points triangulate independently of each other): a
    # detector's frame comes with its lift, so mostly none are.
    missing = np.flatnonzero(weights == 0)
    if not len(missing):
        return targets, weights
    clicks = np.where(obs.click_weights[:, missing, None] > 0, obs.clicks_px[:, missing], np.nan)
    tri = triangulate(clicks, cameras, obs.click_weights[:, missing])
    use = missing[tri.valid]
    targets[use] = tri.points_world[tri.valid]
    weights[use] = tri.inliers[:, tri.valid].sum(0) / len(cameras)
    return targets, weights


def kabsch(source: np.ndarray, target: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t minimising sum w ||R s + t - x||^2 (no scale). (N,3),(N,3),(N,)."""
    w = weights / weights.sum()
    mu_s, mu_t = w @ source, w @ target
    H = ((source - mu_s) * w[:, None]).T @ (target - mu_t)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, mu_t - R @ mu_s


def rank_placements(candidate_keypoints: np.ndarray, candidate_wrists: np.ndarray, targets: np.ndarray,
                    weights: np.ndarray) -> list[Placement]:
    """Align each candidate's rest keypoints to the targets; placements from best to worst.

    Args:
        candidate_keypoints: (M, 21, 3) model keypoints per candidate, zero global pose, metres.
        candidate_wrists: (M, 3) root joint of each candidate (the pivot of global_orient).
        targets: (21, 3) with NaN rows where unknown; weights: (21,).
    """
    ok = np.isfinite(targets).all(1) & (weights > 0)
    if ok.sum() < 3:
        raise ValueError("at least three keypoints must be located in 3D to place the hand")
    placements = []
    for m, (source, wrist) in enumerate(zip(candidate_keypoints, candidate_wrists, strict=True)):
        R, t = kabsch(source[ok], targets[ok], weights[ok])
        residual = float(np.sqrt(np.mean(np.sum((source[ok] @ R.T + t - targets[ok]) ** 2, axis=1))))
        # The layer rotates about the wrist joint J0: x = R (p - J0) + J0 + transl.
        transl = t + R @ wrist - wrist
        placements.append(Placement(m, Rotation.from_matrix(R).as_rotvec(), transl, targets, residual))
    return sorted(placements, key=lambda p: p.residual_m)


def place_hand(candidate_keypoints: np.ndarray, candidate_wrists: np.ndarray, targets: np.ndarray,
               weights: np.ndarray) -> Placement:
    """The best placement of `rank_placements`."""
    return rank_placements(candidate_keypoints, candidate_wrists, targets, weights)[0]
