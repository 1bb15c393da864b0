"""Per-keypoint RANSAC triangulation recovers known points from synthetic 2D keypoints with outlier views."""

from __future__ import annotations

import numpy as np
import pytest

from workers.detector.lifting import keypoint_confidence, lift
from workers.detector.types import ViewKeypoints
from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig
from workers.geometry.triangulation import triangulate

RIG = default_rig(640)


def _hand_points(rng: np.random.Generator) -> np.ndarray:
    """(21, 3) points in a 16 cm cube around the rig's centre, metres."""
    return rng.uniform(-0.08, 0.08, (21, 3))


def _view(pixels: np.ndarray, scores: np.ndarray | None = None) -> ViewKeypoints:
    lo, hi = pixels.min(0), pixels.max(0)
    return ViewKeypoints(pixels, np.full(21, 0.9) if scores is None else scores, 0.95, "right",
                         np.array([*lo, *(hi - lo)]), 0.0)


def test_lift_recovers_points_despite_two_outlier_views() -> None:
    rng = np.random.default_rng(7)
    truth = _hand_points(rng)
    pixels, _ = project_points(truth, RIG)  # (8, 21, 2)
    noisy = pixels + rng.normal(0, 0.5, pixels.shape)
    bad = [2, 5]
    noisy[bad] += rng.uniform(40, 80, (2, 21, 2)) * rng.choice([-1, 1], (2, 21, 2))  # wrong hands in two views
    lifted = lift([_view(p) for p in noisy], RIG)
    err_mm = 1000 * np.linalg.norm(lifted.points_world - truth, axis=1)
    assert np.all(err_mm < 2.0), err_mm.max()
    assert not lifted.inliers[:, bad].any()
    assert lifted.inliers[:, [0, 1, 3, 4, 6, 7]].all()
    assert np.all(lifted.reprojection_px < 2.0)
    assert np.all((lifted.confidence > 0.5) & (lifted.confidence <= 1.0))
    # Naive DLT over all views is far off: the test has teeth.
    naive = triangulate(noisy, RIG, outlier_px=1e9)
    assert np.median(1000 * np.linalg.norm(naive.points_world - truth, axis=1)) > 10


def test_missing_views_and_too_few_views() -> None:
    rng = np.random.default_rng(8)
    truth = _hand_points(rng)
    pixels, _ = project_points(truth, RIG)
    views = [_view(p) for p in pixels]
    views[1] = views[4] = None
    lifted = lift(views, RIG)
    assert np.all(1000 * np.linalg.norm(lifted.points_world - truth, axis=1) < 0.5)
    assert not lifted.inliers[:, [1, 4]].any()
    only_one = [views[0]] + [None] * 7
    lone = lift(only_one, RIG)
    assert np.isnan(lone.points_world).all() and np.isnan(lone.confidence).all()
    assert lone.frame_confidence == 0.0


def test_refinement_lowers_the_reprojection_error_of_weighted_views() -> None:
    """Gauss-Newton over the inliers minimises pixels, which the algebraic DLT does not."""
    rng = np.random.default_rng(9)
    truth = _hand_points(rng)
    pixels, _ = project_points(truth, RIG)
    noisy = pixels + rng.normal(0, 2.0, pixels.shape)
    weights = rng.uniform(0.2, 1.0, (8, 21))
    plain = triangulate(noisy, RIG, weights, outlier_px=1e9)
    refined = triangulate(noisy, RIG, weights, outlier_px=1e9, refine=True)
    cost = []
    for result in (plain, refined):
        proj, _ = project_points(result.points_world, RIG)
        cost.append((weights * ((proj - noisy) ** 2).sum(-1)).sum())
    assert cost[1] < cost[0]
    assert np.all(np.isfinite(refined.median_reprojection_px))


def test_confidence_grows_with_support_and_falls_with_residual() -> None:
    c = keypoint_confidence(np.array([2, 4, 8, 8]), np.array([0.0, 0.0, 0.0, 5.0]), np.full(4, 0.8), outlier_px=5.0)
    assert c[0] < c[1] < c[2] and c[3] < c[2]
    assert c[2] == pytest.approx(0.8 * (1 - 0.5**7))


def test_a_keypoint_two_views_agree_on_far_from_the_hand_is_not_lifted() -> None:
    rng = np.random.default_rng(11)
    truth = _hand_points(rng)
    pixels, _ = project_points(truth, RIG)
    far = truth[5] + np.array([0.0, 0.0, 0.4])  # 40 cm off: two views that agree by chance
    far_px, _ = project_points(far[None], RIG[:2])
    pixels[:2, 5] = far_px[:, 0]
    pixels[2:, 5] += rng.uniform(60, 120, (6, 2)) * rng.choice([-1, 1], (6, 2))  # the others disagree with all
    lifted = lift([_view(p) for p in pixels], RIG)
    assert np.isnan(lifted.points_world[5]).all() and np.isnan(lifted.confidence[5])
    assert not lifted.inliers[5].any()
    others = np.delete(np.arange(21), 5)
    assert np.all(1000 * np.linalg.norm(lifted.points_world[others] - truth[others], axis=1) < 0.5)
