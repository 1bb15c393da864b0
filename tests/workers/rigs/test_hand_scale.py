"""The hand-size scale estimator: synthetic hands at known scales, the plain DLT in a rig's own unit, and the
real two-webcam recording (board-square calibration) when present."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig
from workers.handmodel.keypoints import KEYPOINT_NAMES, SKELETON_EDGES
from workers.handmodel.layer import HandLayer
from workers.handmodel.loading import load_hand_model
from workers.rigs.hand_scale import (
    REFERENCE_BONE_M,
    REFERENCE_HAND_LENGTH_M,
    estimate_hand_scale,
    triangulate_keypoints,
)


def _hands(frames: int, seed: int = 0) -> np.ndarray:
    """(frames, 21, 3) metres: the built-in hand (mean shape) in random poses, near the world origin."""
    torch.manual_seed(seed)
    layer = HandLayer(load_hand_model(None))
    with torch.no_grad():
        return layer(pose=torch.randn(frames, 45) * 0.3).keypoints.numpy().astype(np.float64)


def test_the_reference_bones_are_the_built_in_hands_at_rest() -> None:
    with torch.no_grad():
        rest = HandLayer(load_hand_model(None))().keypoints[0].numpy()
    for parent, child in SKELETON_EDGES:
        length = float(np.linalg.norm(rest[child] - rest[parent]))
        assert abs(REFERENCE_BONE_M[KEYPOINT_NAMES[child]] - length) <= 5e-4, KEYPOINT_NAMES[child]
    assert abs(REFERENCE_HAND_LENGTH_M - float(np.linalg.norm(rest[12] - rest[0]))) <= 1e-3


@pytest.mark.parametrize("scale,verdict", [(1.0, "plausible"), (0.01, "too small"), (20.0, "too large")])
def test_the_factor_undoes_a_known_scale(scale: float, verdict: str) -> None:
    rng = np.random.default_rng(1)
    points = _hands(12) + rng.normal(0.0, 0.002, (12, 21, 3))  # 2 mm noise
    points[rng.random((12, 21)) < 0.15] = np.nan  # missed keypoints
    points[3, 8] += 0.2  # one wild keypoint: the medians ignore it
    size = estimate_hand_scale(points * scale)
    assert size.factor == pytest.approx(1.0 / scale, rel=0.04)
    assert size.verdict == verdict and size.bones == 20 and size.frames == 12
    assert size.hand_length == pytest.approx(REFERENCE_HAND_LENGTH_M * scale, rel=0.04)
    message = size.message()
    if verdict == "plausible":
        assert "scale looks right" in message
    else:
        assert f"scale looks wrong, the hand is {verdict} by" in message
        assert f"--scale set to {size.factor:.4g} times the metres per file unit" in message


def test_too_few_bones_give_no_verdict() -> None:
    points = np.full((3, 21, 3), np.nan)
    points[:, :4] = _hands(3)[:, :4]  # wrist and the thumb's first three keypoints: 3 bones
    size = estimate_hand_scale(points)
    assert size.verdict == "unknown" and size.bones == 3 and np.isnan(size.factor)
    assert "3 of 20 bones measured" in size.message()
    with pytest.raises(ValueError, match=r"points_3d must have shape \(N, 21, 3\)"):
        estimate_hand_scale(np.zeros((21, 3)))


@pytest.mark.parametrize("scale", [1.0, 20.0])
def test_points_without_a_hands_proportions_give_no_verdict(scale: float) -> None:
    """21 random points (no hand: a check run on made-up keypoints, a detector match gone wrong) are judged neither
    right nor wrong in size, at any scale, and the message says why."""
    rng = np.random.default_rng(5)
    for _ in range(20):
        size = estimate_hand_scale(scale * rng.normal(0.0, 0.05, (1, 21, 3)))  # one frame: spread 0.57-1.8 here
        assert size.verdict == "unknown" and size.spread > 0.55, size
    assert "do not have a hand's proportions" in size.message()


@pytest.mark.parametrize("unit_scale", [1.0, 20.0, 0.01])
def test_plain_dlt_works_in_the_rigs_own_unit(unit_scale: float) -> None:
    """The same pixels triangulated with a rig whose lengths are `unit_scale` times too large give a hand
    `unit_scale` times too large: no metric threshold drops keypoints."""
    rig = default_rig(None)
    hands = _hands(3)
    pixels = np.stack([project_points(h, rig)[0] for h in hands], axis=1)  # (C, N, 21, 2)
    pixels[2, 1] = np.nan  # a view without the hand
    scaled = [replace(c, t=c.t * unit_scale) for c in rig]
    points = triangulate_keypoints(pixels, scaled)
    np.testing.assert_allclose(points, hands * unit_scale, rtol=0, atol=1e-6 * unit_scale)
    assert estimate_hand_scale(points).factor == pytest.approx(1.0 / unit_scale, rel=0.04)
    with pytest.raises(ValueError, match=r"pixels must have shape \(C=8, N, 21, 2\)"):
        triangulate_keypoints(pixels[:, 0], scaled)
