"""Hand localisation from masks (robust to a view without the hand) and sparsification curves."""

from __future__ import annotations

import numpy as np
import pytest

from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig
from workers.nets.localisation import LocalisationError, localise_hand, mask_box
from workers.nets.sparsification import sparsification


def _disc_masks(cameras, center, radius_px=6):
    pixels, _ = project_points(center[None], cameras)
    masks = []
    for cam, (u, v) in zip(cameras, pixels[:, 0], strict=True):
        yy, xx = np.mgrid[:cam.height, :cam.width]
        masks.append((xx - u) ** 2 + (yy - v) ** 2 <= radius_px**2)
    return masks


def test_localise_hand_triangulates_box_centres_and_skips_a_view_without_hand():
    cameras = default_rig(128)
    center = np.array([0.03, -0.02, 0.05])
    masks = _disc_masks(cameras, center)
    masks[2][:] = False  # the hand is not in this view
    masks[5][:3, :3] = True  # a speck elsewhere does not count (largest blob wins)
    location = localise_hand(masks, cameras)
    assert np.linalg.norm(location.center_world - center) < 0.005
    assert not location.views_used[2] and np.isnan(location.boxes_px[2]).all()


def test_localise_hand_errors():
    cameras = default_rig(128)
    masks = [np.zeros((c.height, c.width), bool) for c in cameras]
    with pytest.raises(LocalisationError, match="at least two"):
        localise_hand(masks, cameras)
    with pytest.raises(ValueError, match="masks for"):
        localise_hand(masks[:3], cameras)
    with pytest.raises(ValueError, match="expected"):
        localise_hand([np.zeros((10, 10), bool)] * 8, cameras)
    assert np.isnan(mask_box(np.zeros((5, 5), bool))).all()


def test_sparsification_of_a_perfect_confidence_matches_the_oracle():
    rng = np.random.default_rng(0)
    errors = rng.uniform(0, 30, 200)
    perfect = sparsification(errors, -errors)
    assert perfect.ause == pytest.approx(0.0, abs=1e-9)
    assert perfect.curve[0] == pytest.approx(errors.mean())
    random = sparsification(errors, rng.uniform(size=200))
    assert random.ause > 3.0
    assert np.all(np.diff(perfect.oracle) <= 1e-12)  # the oracle only goes down
    with pytest.raises(ValueError):
        sparsification(errors, errors[:5])


def test_localise_hand_ignores_larger_false_blobs_that_do_not_triangulate():
    """A skin-coloured patch of the background can be larger than the hand in some views; it sits at a
    different place in each view's background, so the views do not agree on it."""
    cameras = default_rig(128)
    center = np.array([-0.02, 0.04, 0.01])
    masks = _disc_masks(cameras, center, radius_px=5)
    rng = np.random.default_rng(0)
    for c in (0, 3, 6):  # big distractors in three views
        y, x = rng.integers(15, 80, 2)
        masks[c][y:y + 14, x:x + 14] = True
    location = localise_hand(masks, cameras)
    assert np.linalg.norm(location.center_world - center) < 0.005
    assert location.views_used.sum() == 8
