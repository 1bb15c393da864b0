"""The 3D points a fit is placed from: given 3D keypoints where present, the clicks triangulated for the rest."""

from __future__ import annotations

import dataclasses

import numpy as np

from workers.fitting.init import observed_points_3d
from workers.fitting.inputs import FrameObservations
from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig
from workers.geometry.triangulation import triangulate

RIG = default_rig()


def _frame(seed: int) -> tuple[FrameObservations, np.ndarray]:
    rng = np.random.default_rng(seed)
    points = rng.normal(0, 0.05, (21, 3))
    pixels, _ = project_points(points, RIG)
    clicks = pixels + rng.normal(0, 0.5, pixels.shape)
    clicks[2, 5] += 70.0  # one view far off for one keypoint
    weights = rng.uniform(0.3, 1.0, (len(RIG), 21))
    weights[:7, 20] = 0.0  # one keypoint clicked in a single view: not located
    return FrameObservations(clicks, weights), points


def test_clicks_alone_are_triangulated_with_the_views_that_agree():
    obs, points = _frame(1)
    targets, weights = observed_points_3d(obs, RIG)
    tri = triangulate(obs.clicks_px, RIG, obs.click_weights)
    assert np.array_equal(targets, np.where(tri.valid[:, None], tri.points_world, np.nan), equal_nan=True)
    assert weights[5] == 7 / 8 and weights[0] == 1.0 and weights[20] == 0.0
    assert 1000 * np.abs(targets[:20] - points[:20]).max() < 5.0


def test_given_3d_keypoints_stand_and_only_the_rest_are_triangulated():
    obs, points = _frame(2)
    given = np.full((21, 3), np.nan)
    given[:12] = points[:12] + 0.002
    kp_weights = np.zeros(21)
    kp_weights[:12] = 0.9
    targets, weights = observed_points_3d(dataclasses.replace(obs, keypoints_3d=given, keypoint_3d_weights=kp_weights),
                                          RIG)
    assert np.array_equal(targets[:12], given[:12]) and np.all(weights[:12] == 0.9)
    clicks_only, click_weights = observed_points_3d(obs, RIG)
    assert np.array_equal(targets[12:], clicks_only[12:], equal_nan=True)  # as if no 3D were given
    assert np.array_equal(weights[12:], click_weights[12:])
    assert np.isnan(targets[20]).all() and weights[20] == 0.0
    everything = np.where(np.isfinite(points), points, 0.0)
    all_given = dataclasses.replace(obs, keypoints_3d=everything, keypoint_3d_weights=np.ones(21))
    assert np.array_equal(observed_points_3d(all_given, RIG)[0], everything)
