"""Reweighting a detector's 2D keypoints by a first fit's residuals (workers.fitting.reweight)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from workers.fitting.inputs import FrameObservations
from workers.fitting.reweight import FIRST_FIT_SHARE, fit_reweighted, residual_reweighted
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


@dataclass(frozen=True)
class _Diagnostics:
    iterations: int
    seconds: float


@dataclass(frozen=True)
class _Answer:
    keypoints: np.ndarray
    diagnostics: _Diagnostics


class _RecordingEngine:
    """Stands in for FittingEngine: records the frames it is given and answers each with a fixed hand."""

    def __init__(self, cameras: list[Camera], answers: list[np.ndarray]) -> None:
        self.cameras = cameras
        self.answers = answers
        self.calls: list[list[FrameObservations]] = []

    def prepare_masks(self, frames):
        return object()

    def fit(self, frames, progress=None, prepared=None):
        self.prepared = [prepared]
        self.calls.append(frames)
        if progress is not None:
            progress(0.0, "start")
            progress(1.0, "done")
        n = len(self.calls)
        return [_Answer(self.answers[n - 1], _Diagnostics(iterations=10 * n, seconds=0.1 * n)) for _ in frames]

    def refine(self, frames, earlier, progress=None, prepared=None):
        self.refined_from = earlier
        first_prepared = self.prepared
        answer = self.fit(frames, progress, prepared)
        self.prepared = first_prepared + self.prepared
        return answer


def test_a_detector_frame_is_fitted_again_with_the_first_fits_residuals():
    cameras = _cameras()
    keypoints = np.random.default_rng(5).uniform(-0.05, 0.05, (21, 3))
    clicks, _ = project_points(keypoints, cameras)
    clicks[0, 4] += [25.0, 0.0]  # one detection off the first fit
    obs = FrameObservations(clicks, np.full((2, 21), 0.8), points_source="detector")
    second_answer = keypoints + 0.001
    engine = _RecordingEngine(cameras, [keypoints, second_answer])
    seen: list[float] = []
    results = fit_reweighted(engine, [obs], progress=lambda f, m: seen.append(f))
    assert len(engine.calls) == 2 and engine.calls[0] == [obs]
    expected = residual_reweighted(obs, keypoints, cameras).click_weights
    assert engine.calls[1][0].click_weights == pytest.approx(expected)
    assert engine.calls[1][0].click_weights[0, 4] < 0.8 / 2  # the far detection pulls less the second time
    assert results[0].keypoints is second_answer  # the second fit is the answer
    assert [r.keypoints for r in engine.refined_from] == [keypoints]  # it continues the first
    assert engine.prepared[0] is engine.prepared[1] is not None  # both fits share the masks' preparation
    assert results[0].diagnostics == _Diagnostics(iterations=10 + 20, seconds=pytest.approx(0.1 + 0.2))  # both fits
    assert seen == pytest.approx([0.0, FIRST_FIT_SHARE, FIRST_FIT_SHARE, 1.0])  # progress over both fits
