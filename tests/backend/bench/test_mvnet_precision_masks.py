"""`bench mvnet-precision`'s heuristic compares a prediction's fit with the loop's reference: the chroma key cut at
the prediction's wrist (workers.fitting.reference_masks), not left whole for the fit to cut at its own wrist."""

from __future__ import annotations

import numpy as np
import pytest

from backend.bench.mvnet_precision import prediction_masks
from tests.support.live_stack import tiny_capture
from workers.capture import load_frame_masks, load_ground_truth, read_capture
from workers.fitting.reference_masks import prediction_reference_masks


@pytest.fixture(scope="module")
def frame(capture_cache):
    capture = read_capture(tiny_capture(capture_cache, frames=1, width=160), check_images=False)
    ref = capture.sequences[0].frames[0]
    return list(capture.cameras), load_ground_truth(ref), load_frame_masks(ref)


def test_the_chroma_reference_is_the_loops_cut_at_the_predicted_wrist(frame):
    cameras, truth, chroma = frame
    masks, include_forearm = prediction_masks("chroma_key", truth.hand_masks, chroma, cameras, truth.keypoints_3d)
    loop, sources, _ = prediction_reference_masks([None] * len(cameras), [chroma.get(c.name) for c in cameras],
                                                  cameras, truth.keypoints_3d)
    assert include_forearm is False and sources == ["chroma_key_cut"] * len(cameras)
    for mine, theirs, cam in zip(masks, loop, cameras, strict=True):
        np.testing.assert_array_equal(mine, theirs)
        assert mine.sum() < chroma[cam.name].sum()  # the forearm is gone
    # The cut follows the prediction: a prediction 3 cm further along the forearm keeps more of it.
    axis = truth.keypoints_3d[9] - truth.keypoints_3d[0]
    moved = truth.keypoints_3d - 0.03 * axis / np.linalg.norm(axis)
    more, _ = prediction_masks("chroma_key", truth.hand_masks, chroma, cameras, moved)
    assert sum(m.sum() for m in more) > sum(m.sum() for m in masks)


def test_the_true_hand_masks_are_passed_as_they_are(frame):
    cameras, truth, chroma = frame
    masks, include_forearm = prediction_masks("gt_hand_masks", truth.hand_masks, chroma, cameras, truth.keypoints_3d)
    assert include_forearm is False and all(m is truth.hand_masks[c.name] for m, c in zip(masks, cameras, strict=True))
    with pytest.raises(ValueError, match="mask kind"):
        prediction_masks("handsegnet", truth.hand_masks, chroma, cameras, truth.keypoints_3d)
