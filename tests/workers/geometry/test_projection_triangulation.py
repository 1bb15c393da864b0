"""Projection against OpenCV's, undistortion round trips, and triangulation."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from workers.geometry.projection import (
    project_points,
    project_points_torch,
    project_visible,
    stack_cameras,
    undistort_normalized,
    undistort_pixels,
)
from workers.geometry.rig import default_rig
from workers.geometry.triangulation import triangulate

RIG = default_rig()


def _points(seed: int, n: int = 21, spread_m: float = 0.08) -> np.ndarray:
    return np.random.default_rng(seed).normal(0, spread_m, (n, 3))


def test_projection_matches_opencv():
    points = _points(0)
    pixels, depth = project_points(points, RIG)
    for c, cam in enumerate(RIG):
        ref, _ = cv2.projectPoints(points, cv2.Rodrigues(cam.R)[0], cam.t, cam.K, cam.dist)
        assert np.allclose(pixels[c], ref.reshape(-1, 2), atol=1e-9)
        assert np.allclose(depth[c], (points @ cam.R.T + cam.t)[:, 2])


def test_torch_projection_is_differentiable():
    points = torch.tensor(_points(1)[None], requires_grad=True)
    pixels, _ = project_points_torch(points, **stack_cameras(RIG, dtype=torch.float64))
    pixels.sum().backward()
    assert torch.isfinite(points.grad).all() and points.grad.abs().sum() > 0


def test_the_numpy_and_torch_faces_are_one_projection():
    points = _points(3)
    pixels, depth = project_points(points, RIG)
    assert isinstance(pixels, np.ndarray)
    t_pixels, t_depth = project_points_torch(torch.as_tensor(points[None]), **stack_cameras(RIG, dtype=torch.float64))
    np.testing.assert_allclose(pixels, t_pixels[0].numpy(), atol=1e-10)
    np.testing.assert_allclose(depth, t_depth[0].numpy(), atol=1e-14)


def test_project_visible_leaves_unseen_points_out():
    cam = RIG[0]
    behind = cam.center_world - 0.1 * cam.R[2]  # 10 cm behind the camera, on its axis
    points = np.stack([_points(4, n=1)[0], behind, [np.nan, 0.0, 0.0]])
    out = project_visible(points, cam)
    np.testing.assert_allclose(out[0], project_points(points[:1], [cam])[0][0, 0])
    assert np.isnan(out[1:]).all()


def test_fixed_point_undistortion_takes_opencvs_steps():
    cam = RIG[3]
    pixels, _ = project_points(_points(5, spread_m=0.15), [cam])
    yd = (pixels[0, :, 1] - cam.K[1, 2]) / cam.K[1, 1]
    xd = (pixels[0, :, 0] - cam.K[0, 2]) / cam.K[0, 0]
    for steps in (1, 3, 20):
        ref = cv2.undistortPoints(pixels[0].reshape(-1, 1, 2), cam.K, cam.dist,
                                  criteria=(cv2.TERM_CRITERIA_COUNT, steps, 0)).reshape(-1, 2)
        np.testing.assert_allclose(np.stack(undistort_normalized(xd, yd, cam.dist, steps), -1), ref, atol=1e-12)
        one = undistort_normalized(float(xd[0]), float(yd[0]), [float(k) for k in cam.dist], steps)
        np.testing.assert_allclose(one, ref[0], atol=1e-12)


def test_undistort_inverts_distortion():
    cam = RIG[3]  # a 4 mm lens: the strongest distortion in the rig
    points = _points(2, spread_m=0.15)
    pixels, _ = project_points(points, [cam])
    ideal = (points @ cam.R.T + cam.t) @ cam.K.T
    ideal = ideal[:, :2] / ideal[:, 2:]
    assert np.abs(pixels[0] - ideal).max() > 0.5  # distortion matters at this spread
    assert np.allclose(undistort_pixels(pixels[0], cam), ideal, atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(*[st.floats(-0.15, 0.15)] * 3), min_size=1, max_size=8))
def test_project_then_triangulate_returns_the_points(points):
    points = np.asarray(points)
    pixels, _ = project_points(points, RIG)
    result = triangulate(pixels, RIG)
    assert result.valid.all()
    assert np.abs(result.points_world - points).max() < 1e-6
    assert result.inliers.all()


def test_outlier_view_is_rejected():
    points = _points(3)
    pixels, _ = project_points(points, RIG)
    noisy = pixels + np.random.default_rng(0).normal(0, 0.5, pixels.shape)
    noisy[5] += 60.0  # one view clicked far off
    result = triangulate(noisy, RIG)
    assert not result.inliers[5].any()
    error_mm = 1000 * np.linalg.norm(result.points_world - points, axis=1)
    assert error_mm.max() < 3.0
    # A plain least-squares solution over all views is dragged away by the outlier.
    naive = triangulate(noisy, RIG, outlier_px=1e9)
    assert 1000 * np.linalg.norm(naive.points_world - points, axis=1).mean() > 2 * error_mm.mean()


@pytest.mark.parametrize("refine", [False, True])
def test_points_triangulated_together_equal_points_triangulated_alone(refine):
    """All points' two-view hypotheses go through one batch: no point's views, outliers or weights may reach
    another's. Each point here has its own missing views, outlier views and weights."""
    rng = np.random.default_rng(7)
    points = _points(8, n=12)
    pixels, _ = project_points(points, RIG)
    pixels = pixels + rng.normal(0, 0.7, pixels.shape)
    weights = rng.uniform(0.2, 1.0, pixels.shape[:2])
    for n in range(12):
        views = rng.choice(len(RIG), size=n % 4, replace=False)
        pixels[views[: len(views) // 2], n] += rng.uniform(30, 80, 2)  # outlier views
        weights[views[len(views) // 2:], n] = 0.0  # views that did not see the point
    pixels[:7, 11] = np.nan  # a point seen by one view only: not triangulated
    together = triangulate(pixels, RIG, weights, refine=refine)
    assert together.valid[:11].all() and not together.valid[11]
    for n in range(12):
        alone = triangulate(pixels[:, n: n + 1], RIG, weights[:, n: n + 1], refine=refine)
        assert np.array_equal(alone.points_world[0], together.points_world[n], equal_nan=True)
        assert np.array_equal(alone.inliers[:, 0], together.inliers[:, n])
    assert 1000 * np.linalg.norm(together.points_world[:11] - points[:11], axis=1).max() < 5.0  # outliers out


def test_weights_missing_views_and_too_few_views():
    points = _points(4, n=3)
    pixels, _ = project_points(points, RIG)
    pixels[:, 0] = np.nan
    pixels[2:, 0] = pixels[2:, 1]  # point 0 only in views 2..7 with values of point 1
    pixels[:, 2] = np.nan
    pixels[0, 2] = 10.0  # point 2: a single view
    weights = np.ones((8, 3))
    weights[:, 1] = 0.0
    weights[:2, 1] = 1.0  # point 1 from two views only
    result = triangulate(pixels, RIG, weights)
    assert np.allclose(result.points_world[0], points[1], atol=1e-6)
    assert np.allclose(result.points_world[1], points[1], atol=1e-6)
    assert not result.valid[2] and np.isnan(result.points_world[2]).all()


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"pixels": np.zeros((7, 2, 2))}, "pixels must have shape"),
    ({"weights": -np.ones((8, 2))}, "weights must be finite and non-negative"),
    ({"weights": np.ones((8, 3))}, "weights must have shape"),
])
def test_bad_triangulation_input(kwargs, message):
    args = {"pixels": np.zeros((8, 2, 2)), "cameras": RIG} | kwargs
    with pytest.raises(ValueError, match=message):
        triangulate(**args)
