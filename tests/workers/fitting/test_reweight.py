"""Reweighting a detector's 2D keypoints by a first fit's residuals (workers.fitting.reweight)."""

from __future__ import annotations

import numpy as np
import pytest

from workers.fitting.inputs import FrameObservations
from workers.fitting.reweight import residual_reweighted
from workers.geometry.camera import Camera
from workers.geometry.projection import project_points


def _cameras() -> list[Camera]:
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    out = []
    for angle in (-0.3, 0.3):
        c, s = np.cos(angle), np.sin(angle)
        R = np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])
        out.append(Camera(name=f"cam{angle}", K=K, dist=np.zeros(5), R=R, t=np.array([0.0, 0.0, 0.5]),
                          width=640, height=480))
    return out


def test_a_keypoint_far_from_the_fit_pulls_less_and_one_on_it_keeps_its_weight():
    cameras = _cameras()
    rng = np.random.default_rng(3)
    keypoints = rng.uniform(-0.05, 0.05, (21, 3))
    pixels, _ = project_points(keypoints, cameras)
    clicks = pixels.copy()
    hand_px = np.ptp(pixels, axis=1).max(axis=1)
    clicks[0, 4] += [0.05 * hand_px[0], 0.0]  # one residual of exactly the scale: half its weight
    clicks[1, 8] += [0.0, 10 * 0.05 * hand_px[1]]  # ten scales off: 1 / 101
    clicks[1, 12] = np.nan  # no detection
    weights = np.full((2, 21), 0.8)
    weights[1, 12] = 0.0
    obs = FrameObservations(clicks, weights, points_source="detector")
    out = residual_reweighted(obs, keypoints, cameras)
    expected = np.full((2, 21), 0.8)
    expected[0, 4] = 0.4
    expected[1, 8] = 0.8 / 101
    expected[1, 12] = 0.0
    assert out.click_weights == pytest.approx(expected, rel=1e-6)
    assert out.clicks_px is obs.clicks_px and out.points_source == "detector"
    assert obs.click_weights[0, 4] == 0.8  # the input is not changed
    with pytest.raises(ValueError, match="scale_fraction"):
        residual_reweighted(obs, keypoints, cameras, scale_fraction=0.0)
