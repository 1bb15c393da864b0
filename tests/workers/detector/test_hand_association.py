"""Several hands without the model: epipolar distances, mask blobs, chirality, the cross-view grouping that keeps
the requested side's hand, and the sequence check on the declared side."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from workers.detector.association import choose_hand, hand_groups
from workers.detector.crops import mask_windows
from workers.detector.handedness import chirality, side_disagreement, side_of
from workers.detector.types import ViewKeypoints
from workers.geometry.epipolar import symmetric_epipolar_distances
from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig
from workers.handmodel import HandLayer, load_hand_model
from workers.handmodel.pose_sampler import sampler_for

RIG = default_rig(320)


def _posed_keypoints(side: str, count: int, seed: int) -> np.ndarray:
    """(count, 21, 3) keypoints of the built-in hand of `side` in sampled poses and random orientations, metres."""
    rng = np.random.default_rng(seed)
    arrays = load_hand_model(None, side)
    layer = HandLayer(arrays, dtype=torch.float64)
    poses = sampler_for(arrays).sample(count, rng)
    with torch.no_grad():
        out = layer(torch.zeros(count, 10, dtype=torch.float64), torch.as_tensor(poses),
                    torch.as_tensor(rng.normal(0, 2, (count, 3))), torch.zeros(count, 3, dtype=torch.float64))
    keypoints = out.keypoints.numpy()
    return keypoints - keypoints[:, :1]  # wrists at the origin


def _view(pixels: np.ndarray, right_score: float = float("nan"), presence: float = 0.9) -> ViewKeypoints:
    lo, hi = pixels.min(0), pixels.max(0)
    return ViewKeypoints(pixels, np.full(21, 0.9), presence, "right", np.array([*lo, *(hi - lo)]), 0.0, right_score)


def test_epipolar_distance_is_zero_for_one_point_and_grows_off_it() -> None:
    rng = np.random.default_rng(3)
    points = rng.uniform(-0.08, 0.08, (21, 3))
    pixels, _ = project_points(points, RIG[:2])
    assert np.all(symmetric_epipolar_distances(pixels[0], pixels[1], RIG[0], RIG[1]) < 1e-6)
    # A 10 px move along x or along y: one of them leaves the epipolar line by at least 10 / sqrt(2) px in view 1.
    moved = np.maximum(*(symmetric_epipolar_distances(pixels[0], pixels[1] + step, RIG[0], RIG[1])
                         for step in ([10.0, 0.0], [0.0, 10.0])))
    assert np.all(moved > 3.0)


def test_mask_windows_take_each_large_blob_largest_first() -> None:
    mask = np.zeros((100, 100), bool)
    mask[10:30, 40:50] = True  # 200 px
    mask[60:75, 60:70] = True  # 150 px: a second hand
    mask[80:82, 5:7] = True  # a speck
    windows = mask_windows(mask, 1.5)
    assert [w[:2] for w in windows] == [pytest.approx((44.5, 19.5)), pytest.approx((64.5, 67.0))]
    assert mask_windows(mask, 1.5, max_count=1) == windows[:1] and mask_windows(np.zeros((9, 9), bool), 1.5) == []


def test_chirality_tells_right_from_left_hands() -> None:
    right, left = _posed_keypoints("right", 50, 1), _posed_keypoints("left", 50, 2)
    assert np.mean([chirality(k) > 0.1 for k in right]) >= 0.95
    assert np.mean([chirality(k) < -0.1 for k in left]) >= 0.95
    mirrored = right * [-1.0, 1.0, 1.0]  # a mirror image of a right hand is a left hand
    assert np.all(np.sign([chirality(k) for k in mirrored]) == -np.sign([chirality(k) for k in right]))
    unlifted = right[0].copy()
    unlifted[4] = np.nan
    assert np.isnan(chirality(unlifted))
    # No lift: the views' handedness vote, weighted by presence.
    assert side_of(None, [_view(np.zeros((21, 2)), 0.9, 0.2), _view(np.zeros((21, 2)), 0.2, 0.9)]) == "left"
    assert side_of(None, [None, _view(np.zeros((21, 2)))]) is None


@pytest.mark.parametrize("side", ["right", "left"])
def test_the_requested_hand_is_chosen_in_every_view(side: str) -> None:
    """Two hands 16 cm apart in all 8 views, in shuffled order per view, the model's handedness unknown: the groups
    split by epipolar distance, and the lift's chirality picks the requested side's in every view."""
    rng = np.random.default_rng(11)
    truth = {"right": _posed_keypoints("right", 1, 5)[0] + [-0.08, 0, 0],
             "left": _posed_keypoints("left", 1, 6)[0] + [0.08, 0, 0]}
    pixels = {s: project_points(k, RIG)[0] + rng.normal(0, 0.5, (len(RIG), 21, 2)) for s, k in truth.items()}
    candidates, order = [], []
    for c in range(len(RIG)):
        sides = list(rng.permutation(["right", "left"]))
        order.append(sides)
        candidates.append([_view(pixels[s][c]) for s in sides])
    groups = hand_groups(candidates, RIG)
    assert [len(g.members) for g in groups[:2]] == [8, 8] and {g.side for g in groups[:2]} == {"right", "left"}
    chosen = choose_hand(candidates, RIG, side)
    assert all(v is candidates[c][order[c].index(side)] for c, v in enumerate(chosen))


def test_one_hand_per_view_is_kept_as_it_is() -> None:
    views = [[_view(np.random.default_rng(c).uniform(0, 300, (21, 2)), 0.1)] for c in range(3)] + [[]]
    chosen = choose_hand(views, RIG[:4], "right")
    assert chosen[:3] == [v[0] for v in views[:3]] and chosen[3] is None


def test_a_sequence_of_the_other_side_is_noted() -> None:
    assert side_disagreement(["left"] * 5 + ["right", None], "right") is not None
    assert "a right hand was asked for" in side_disagreement(["left"] * 3, "right")
    assert side_disagreement(["left", "left", "right", "right"], "right") is None
    assert side_disagreement(["left", "left", None], "right") is None  # too few frames say anything
