"""The heuristic's IoU reference for a prediction's fit (setting `heuristic_iou_reference`): on green-screen
views the chroma-key foreground cut at MVNet's predicted wrist; a fit that matches the hand passes the
paper's IoU criterion against it and one that misses it fails; 'handsegnet' restores HandSegNet's masks."""

from __future__ import annotations

import numpy as np
import pytest

from backend.services.review.verification import HeuristicThresholds, heuristic_verdict
from tests.support.live_stack import tiny_capture
from workers.capture import load_frame_masks, load_ground_truth, read_capture
from workers.handmodel.builtin import build_builtin_hand
from workers.rendering import model_mask
from workers.tasks.inputs import prediction_reference_masks
from workers.tasks.records import iou_reference


@pytest.fixture(scope="module")
def frame(capture_cache):
    capture = read_capture(tiny_capture(capture_cache, frames=1, width=320), check_images=False)
    ref = capture.sequences[0].frames[0]
    chroma = load_frame_masks(ref)
    assert chroma, "the tiny capture is a green-screen capture"
    cameras = list(capture.cameras)
    truth = load_ground_truth(ref)
    faces = build_builtin_hand().faces  # the capture's hand model: the true fit's silhouette per view
    fits = [model_mask(truth.vertices, faces, c) for c in cameras]
    return cameras, [chroma.get(c.name) for c in cameras], truth, fits


def _ious(fit_masks, reference):
    out = []
    for fit, ref in zip(fit_masks, reference, strict=True):
        if ref is not None:
            out.append(np.logical_and(fit, ref).sum() / max(1, np.logical_or(fit, ref).sum()))
    return out


def _verdict(truth, ious):
    kp = truth.keypoints_3d  # a confident prediction on the fit's keypoints: only the IoU can fail
    return heuristic_verdict([0.95] * 21, ious, kp, kp, HeuristicThresholds())


def test_a_fit_matching_the_chroma_hand_passes_and_one_missing_it_fails(frame):
    cameras, chroma, truth, fits = frame
    handsegnet = [None] * len(cameras)
    masks, sources, include_forearm = prediction_reference_masks(handsegnet, chroma, cameras, truth.keypoints_3d)
    assert sources == ["chroma_key_cut"] * len(cameras) and include_forearm is False
    # The cut removes the forearm: the reference is smaller than the chroma key, and holds the hand.
    assert sum(m.sum() for m in masks) < 0.8 * sum(m.sum() for m in chroma)
    matching = _ious(fits, masks)
    verdict = _verdict(truth, matching)
    assert verdict.accepted, verdict.failed
    assert np.mean(matching) >= 0.7
    # A fit 20 % of the image width to the side misses the hand.
    shift = cameras[0].width // 5
    missing = _ious([np.roll(f, shift, axis=1) for f in fits], masks)
    verdict = _verdict(truth, missing)
    assert not verdict.accepted and any("IoU" in f for f in verdict.failed)
    assert np.mean(missing) < 0.5


def test_the_cut_follows_the_prediction_not_the_fit(frame):
    """A prediction far off the hand cuts the chroma key elsewhere: even the true hand then fails."""
    cameras, chroma, truth, fits = frame
    wrong = truth.keypoints_3d.copy()
    axis = wrong[9] - wrong[0]
    wrong = wrong + axis  # the whole prediction moved by a palm length along the hand axis
    masks, _, _ = prediction_reference_masks([None] * len(cameras), chroma, cameras, wrong)
    assert np.mean(_ious(fits, masks)) < 0.7


def test_views_without_a_chroma_key_and_the_setting_off_use_handsegnet(frame):
    cameras, chroma, truth, _ = frame
    segnet = [np.roll(truth.hand_masks[c.name], 3, axis=0) for c in cameras]
    partial = [m if c % 2 else None for c, m in enumerate(chroma)]
    masks, sources, _ = prediction_reference_masks(segnet, partial, cameras, truth.keypoints_3d)
    assert sources == ["handsegnet" if c % 2 == 0 else "chroma_key_cut" for c in range(len(cameras))]
    assert all(masks[c] is segnet[c] or np.array_equal(masks[c], segnet[c]) for c in range(0, len(cameras), 2))
    assert iou_reference({"iou_reference": dict(enumerate(sources))}) == "mixed"

    masks, sources, include_forearm = prediction_reference_masks(segnet, chroma, cameras, truth.keypoints_3d,
                                                                 "handsegnet")
    assert sources == ["handsegnet"] * len(cameras) and include_forearm is False
    assert all(np.array_equal(m, s) for m, s in zip(masks, segnet, strict=True))
    assert iou_reference({"iou_reference": dict(enumerate(sources))}) == "handsegnet"
    # HandSegNet found no hand anywhere: the chroma key, uncut, for the fit to cut (the paper-path fallback).
    masks, sources, include_forearm = prediction_reference_masks([None] * len(cameras), chroma, cameras,
                                                                 truth.keypoints_3d, "handsegnet")
    assert sources == ["chroma_key"] * len(cameras) and include_forearm is True
    with pytest.raises(ValueError, match="heuristic_iou_reference"):
        prediction_reference_masks(segnet, chroma, cameras, truth.keypoints_3d, "truth")
