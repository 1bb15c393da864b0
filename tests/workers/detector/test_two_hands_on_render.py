"""Two hands in every view of a rendered sequence (issue 36): the sequence's hand is the one kept in every view, and
a photograph with both gives each side's hand on request."""

from __future__ import annotations

import numpy as np
import pytest

from tests.support.two_hands import TwoHandFrame, render_two_hands
from workers.detector import detect_frame
from workers.detector.handedness import lifted_side
from workers.detector.pipeline import detect_frame_hands, detect_image, detect_image_hands
from workers.geometry.camera import Camera

OTHER = {"right": "left", "left": "right"}
# Views where the hand shows fewer pixels than this (hidden behind the other) need not find it.
MIN_VISIBLE_PX = 500


@pytest.fixture(scope="module")
def two_hands() -> tuple[list[Camera], list[TwoHandFrame]]:
    """2 frames at 320 px, a right and a left hand 16 cm apart in all 8 views, chroma-key masks of both."""
    return render_two_hands(seed=31, frames=2)


def _median_px(keypoints: np.ndarray, truth: np.ndarray) -> float:
    return float(np.median(np.linalg.norm(keypoints - truth, axis=1)))


@pytest.mark.usefixtures("require_detector")
@pytest.mark.parametrize("side", ["right", "left"])
def test_the_sequences_hand_is_chosen_in_every_view(two_hands: tuple[list[Camera], list[TwoHandFrame]],
                                                    side: str) -> None:
    cameras, frames = two_hands
    for f, frame in enumerate(frames):
        lifted = detect_frame(frame.images, cameras, frame.masks, handedness=side)
        relative_errors = []
        for c, view in enumerate(lifted.views):
            own, other = frame.keypoints_2d[side][c], frame.keypoints_2d[OTHER[side]][c]
            if view is None:
                assert frame.visible_px[side][c] < MIN_VISIBLE_PX, f"frame {f} view {c}: the {side} hand not found"
                continue
            where = f"frame {f} view {c} ({side})"
            assert _median_px(view.keypoints_px, own) < _median_px(view.keypoints_px, other), f"{where}: other hand"
            relative_errors.append(_median_px(view.keypoints_px, own) / np.ptp(own, axis=0).max())
        # The detector's own error on these 40-60 px hands: ~12 % of the hand's box, up to ~35 % in a view.
        assert len(relative_errors) >= 6 and np.median(relative_errors) < 0.2, (f, side, relative_errors)
        err_mm = 1000 * np.linalg.norm(lifted.points_world - frame.keypoints_3d[side], axis=1)
        assert np.nanmedian(err_mm) < 25.0, (f, side, err_mm)
        assert lifted_side(lifted) == side


@pytest.mark.usefixtures("require_detector")
def test_a_two_hand_photograph_gives_the_hand_of_each_side(two_hands: tuple[list[Camera], list[TwoHandFrame]]
                                                           ) -> None:
    """The view of frame 0 where both hands show most (the larger of the two smaller hand areas), no box."""
    _, frames = two_hands
    frame = frames[0]
    c = int(np.argmax(np.minimum(frame.visible_px["right"], frame.visible_px["left"])))
    image = frame.images[c]
    assert len(detect_image_hands(image)) >= 2
    found = {side: detect_image(image, handedness=side) for side in ("right", "left")}
    for side, view in found.items():
        assert view is not None and view.handedness == side
        own, other = frame.keypoints_2d[side][c], frame.keypoints_2d[OTHER[side]][c]
        # 30 %: this view shows the left hand's fingers edge-on, the detector's own error there is ~26 %.
        assert _median_px(view.keypoints_px, own) < min(0.3 * np.ptp(own, axis=0).max(),
                                                        _median_px(view.keypoints_px, other)), side
    assert found["right"].right_score > found["left"].right_score


@pytest.mark.usefixtures("require_detector")
def test_every_hand_of_a_frame_is_lifted_with_its_side(two_hands: tuple[list[Camera], list[TwoHandFrame]]) -> None:
    """The building block for one sample per hand: both hands of a frame, each lifted near its truth."""
    cameras, frames = two_hands
    frame = frames[0]
    hands = detect_frame_hands(frame.images, cameras, frame.masks)
    assert [side for side, _ in hands[:2]] in (["right", "left"], ["left", "right"])
    for side, lifted in hands[:2]:
        err_mm = 1000 * np.linalg.norm(lifted.points_world - frame.keypoints_3d[side], axis=1)
        assert np.nanmedian(err_mm) < 25.0 and np.isfinite(err_mm).sum() >= 15, (side, err_mm)
