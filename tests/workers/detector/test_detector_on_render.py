"""The detector on rendered hands of a synthetic capture: keypoints in the hand's mask, a lift near the truth."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from workers.capture import load_frame_images, load_frame_masks, load_ground_truth, read_capture
from workers.detector import detect_frame
from workers.detector.pipeline import detect_image


@pytest.fixture
def frames(rendered_capture: Path, require_detector: None) -> tuple[list, list]:
    capture = read_capture(rendered_capture)
    sequence = capture.sequences[0]
    assert sequence.green_screen, "the fixture's seed must give a green-screen sequence"
    return list(capture.cameras), list(sequence.frames)


def _in_mask_fraction(keypoints: np.ndarray, mask: np.ndarray, dilate_px: int) -> float:
    grown = cv2.dilate(mask.astype(np.uint8), np.ones((2 * dilate_px + 1,) * 2, np.uint8)) > 0
    xy = np.round(keypoints).astype(int)
    inside = (xy[:, 0] >= 0) & (xy[:, 0] < mask.shape[1]) & (xy[:, 1] >= 0) & (xy[:, 1] < mask.shape[0])
    hits = np.zeros(len(xy), bool)
    hits[inside] = grown[xy[inside, 1], xy[inside, 0]]
    return float(hits.mean())


def test_keypoints_fall_in_the_hand_mask_and_lift_near_the_truth(frames: tuple[list, list]) -> None:
    cameras, refs = frames
    for ref in refs:
        images, chroma, gt = load_frame_images(ref, cameras), load_frame_masks(ref), load_ground_truth(ref)
        lifted = detect_frame([images[c.name] for c in cameras], cameras, [chroma[c.name] for c in cameras])
        found = [c for c, v in enumerate(lifted.views) if v is not None]
        assert len(found) >= 5, f"hand found in only {len(found)} of {len(cameras)} views"
        for c in found:
            view = lifted.views[c]
            hand = gt.hand_masks[cameras[c].name]
            if hand.sum() < 200:
                continue  # the hand is mostly hidden in this view: nothing to compare with
            assert view.keypoints_px.shape == (21, 2) and view.scores.shape == (21,)
            assert 0 <= view.presence <= 1 and np.all((view.scores >= 0) & (view.scores <= 1))
            # 4 px of slack: keypoints sit on joints, some at the silhouette's edge.
            assert _in_mask_fraction(view.keypoints_px, hand, 4) >= 0.7, cameras[c].name
        err_mm = 1000 * np.linalg.norm(lifted.points_world - gt.keypoints_3d, axis=1)
        assert np.nanmedian(err_mm) < 25.0, err_mm
        assert lifted.inliers.sum(axis=1).min() >= 2


def test_left_hand_by_mirroring(frames: tuple[list, list]) -> None:
    """A mirrored image of the right hand is a left hand: detected with --left, its keypoints mirror back."""
    cameras, refs = frames
    images, gt = load_frame_images(refs[0], cameras), load_ground_truth(refs[0])
    c = int(np.argmax([gt.hand_masks[cam.name].sum() for cam in cameras]))
    image = images[cameras[c].name]
    width = image.shape[1]
    truth = gt.keypoints_2d[c]
    right = detect_image(image)
    left = detect_image(np.ascontiguousarray(image[:, ::-1]), handedness="left")
    assert right is not None and left is not None and left.handedness == "left"
    back = left.keypoints_px.copy()
    back[:, 0] = width - 1 - back[:, 0]
    box = np.ptp(truth, axis=0).max()
    assert np.median(np.linalg.norm(right.keypoints_px - truth, axis=1)) < 0.2 * box
    assert np.median(np.linalg.norm(back - truth, axis=1)) < 0.2 * box


def test_a_view_that_finds_nothing_looks_again_where_the_others_put_the_hand(
        frames: tuple[list, list], monkeypatch: pytest.MonkeyPatch) -> None:
    from workers.detector import pipeline

    cameras, refs = frames
    images, chroma, gt = load_frame_images(refs[0], cameras), load_frame_masks(refs[0]), load_ground_truth(refs[0])
    c = int(np.argmax([gt.hand_masks[cam.name].sum() for cam in cameras]))
    blind = images[cameras[c].name]
    real_searches = pipeline.hand_searches
    # The view's own search (mask, palm detector) finds nothing: only the other views' lift can place its window.
    monkeypatch.setattr(pipeline, "hand_searches",
                        lambda image, mask, palms: [] if image is blind else real_searches(image, mask, palms))
    lifted = detect_frame([images[cam.name] for cam in cameras], cameras, [chroma[cam.name] for cam in cameras])
    view = lifted.views[c]
    assert view is not None, "the second look found nothing"
    assert _in_mask_fraction(view.keypoints_px, gt.hand_masks[cameras[c].name], 4) >= 0.7
    assert lifted.inliers[:, c].sum() >= 10


@pytest.mark.usefixtures("require_detector")
def test_a_left_hand_capture_lifts_near_the_truth(rendered_left_capture: Path) -> None:
    capture = read_capture(rendered_left_capture)
    cameras, ref = list(capture.cameras), capture.sequences[0].frames[0]
    images, chroma, gt = load_frame_images(ref, cameras), load_frame_masks(ref), load_ground_truth(ref)
    lifted = detect_frame([images[c.name] for c in cameras], cameras, [chroma[c.name] for c in cameras],
                          handedness="left")
    assert all(v is None or v.handedness == "left" for v in lifted.views)
    assert sum(v is not None for v in lifted.views) >= 5
    assert np.nanmedian(1000 * np.linalg.norm(lifted.points_world - gt.keypoints_3d, axis=1)) < 25.0
