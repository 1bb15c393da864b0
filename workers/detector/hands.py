"""Every hand in one view: one detection per search (`view.hand_searches`), duplicates of one hand merged, and the
hand of one side among them where there is no second view to decide."""

from __future__ import annotations

import numpy as np

from workers.detector.landmark_model import LandmarkModel
from workers.detector.types import Handedness, ViewKeypoints
from workers.detector.view import StartCrop, detect_view

# Two detections are one hand when their keypoints lie this close (median over the 21, as a fraction of the larger
# hand's size, the longer side of its keypoints' box). Two hands side by side are a hand's size apart or more.
SAME_HAND_FRACTION = 0.25


def hand_size_px(view: ViewKeypoints) -> float:
    """The longer side of the keypoints' box, pixels."""
    return max(float(np.ptp(view.keypoints_px, axis=0).max()), 1.0)


def same_hand(a: ViewKeypoints, b: ViewKeypoints) -> bool:
    distance = float(np.median(np.linalg.norm(a.keypoints_px - b.keypoints_px, axis=1)))
    return distance < SAME_HAND_FRACTION * max(hand_size_px(a), hand_size_px(b))


def view_hands(model: LandmarkModel, image: np.ndarray, searches: list[list[StartCrop]],
               handedness: Handedness = "right") -> list[ViewKeypoints]:
    """Every hand the searches find in `image` (H, W, 3) uint8 RGB, in search order; a hand found again by a later
    search is dropped (the first search is the one-hand search of before, so a one-hand view reads as it did).

    Args:
        handedness: the side each hand is read as (a left hand is shown mirrored); every hand's `right_score` says
            which side the model thinks it is.
    """
    hands: list[ViewKeypoints] = []
    for starts in searches:
        hand = detect_view(model, image, starts, handedness)
        if hand is not None and not any(same_hand(hand, kept) for kept in hands):
            hands.append(hand)
    return hands


def hand_of_side(hands: list[ViewKeypoints], handedness: Handedness) -> ViewKeypoints | None:
    """One view's hand of `handedness` by the model's own handedness (`right_score`): of several hands the one it
    finds most right-handed for "right", least for "left" (relative, not against 0.5: its handedness is weak on some
    views, docs/detector.md); a single hand whatever its side; None for none."""
    scored = [h for h in hands if np.isfinite(h.right_score)]
    if len(hands) < 2 or not scored:
        return hands[0] if hands else None
    pick = max if handedness == "right" else min
    return pick(scored, key=lambda h: h.right_score)
