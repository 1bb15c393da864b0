"""detect_frame: every hand in every view, the hand of the side asked for chosen consistently over the views, a
second look where a view found nothing or disagrees, and the lift. detect_image: the same for one photograph.

Several hands in view (#36): each view's hands (`hands.view_hands`) are grouped across views by the cameras'
epipolar geometry and the group of the side asked for is kept (`association.choose_hand`); views with one hand each
read as before. Where a view finds no hand from its mask or the palm detector, or one that the lift does not use (an
inlier for fewer than MIN_INLIER_KEYPOINTS keypoints), the keypoints lifted from the other views give a window: their
projection into that view, turned upright by the projected wrist -> middle MCP.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from workers.detector.association import choose_hand, hand_groups
from workers.detector.crops import Crop
from workers.detector.hands import hand_of_side, view_hands
from workers.detector.landmark_model import LandmarkModel, landmark_model
from workers.detector.lifting import lift
from workers.detector.model_files import loaded_detector_status as detector_status  # noqa: F401  (re-exported: the workers' check, runtime imported)
from workers.detector.palm import palm_detector
from workers.detector.types import DetectorInputError, Handedness, LiftedKeypoints, ViewKeypoints
from workers.detector.view import MAX_HANDS, StartCrop, detect_view, hand_searches, refined_crop
from workers.geometry.camera import Camera
from workers.geometry.projection import project_points

# A second look needs this many lifted keypoints (the wrist and middle MCP among them) to place its window.
MIN_LIFTED = 12
# A view whose detection is an inlier for fewer keypoints than this disagrees with the others: it looks again.
MIN_INLIER_KEYPOINTS = 3
# Side of the window around a user's box (handloop detect --box) over the box's longer side.
BOX_SCALE = 1.2
# A second look's detection (or another hand of the view) counts only this near the projection of the lifted hand
# (median keypoint distance over the projected hand's size): farther, it is the other hand.
SECOND_LOOK_FRACTION = 0.3


def check_image(image: np.ndarray, where: str) -> np.ndarray:
    """An (H, W, 3) uint8 image, or DetectorInputError naming `where`."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8 or min(image.shape[:2]) < 8:
        raise DetectorInputError(f"{where}: expected an (H, W, 3) uint8 RGB image of at least 8 x 8 pixels, "
                                 f"got shape {image.shape} {image.dtype}")
    return image


def _check_inputs(images: Sequence[np.ndarray], cameras: Sequence[Camera],
                  masks: Sequence[np.ndarray | None] | None) -> list[np.ndarray | None]:
    if len(cameras) < 2:
        raise DetectorInputError(f"multi-view detection needs at least 2 calibrated views, got {len(cameras)}")
    if len(images) != len(cameras):
        raise DetectorInputError(f"{len(images)} images for {len(cameras)} cameras")
    for image, cam in zip(images, cameras, strict=True):
        image = check_image(image, f"view {cam.name}")
        if image.shape[:2] != (cam.height, cam.width):
            raise DetectorInputError(f"view {cam.name}: image is {image.shape[1]}x{image.shape[0]}, its calibration "
                                     f"says {cam.width}x{cam.height}")
    masks = list(masks) if masks is not None else [None] * len(cameras)
    if len(masks) != len(cameras):
        raise DetectorInputError(f"{len(masks)} masks for {len(cameras)} cameras")
    for mask, cam in zip(masks, cameras, strict=True):
        if mask is not None and np.shape(mask) != (cam.height, cam.width):
            raise DetectorInputError(f"view {cam.name}: mask has shape {np.shape(mask)}, expected "
                                     f"({cam.height}, {cam.width})")
    return [None if m is None else np.asarray(m, dtype=bool) for m in masks]


def projected_keypoints(lifted: LiftedKeypoints, camera: Camera) -> np.ndarray | None:
    """(21, 2) pixels of the lifted keypoints in `camera` (unlifted ones at the mean of the rest), or None when too
    few were lifted (fewer than MIN_LIFTED, or no wrist or middle MCP to orient a crop by) or any lies behind it."""
    finite = np.isfinite(lifted.points_world).all(axis=1)
    if finite.sum() < MIN_LIFTED or not finite[[0, 9]].all():
        return None
    uv, depth = project_points(lifted.points_world[finite], [camera])
    if np.any(depth[0] <= 0) or not np.all(np.isfinite(uv)):
        return None
    out = np.empty((21, 2))
    out[finite] = uv[0]
    out[~finite] = uv[0].mean(axis=0)
    return out


def _second_look(model: LandmarkModel, image: np.ndarray, camera: Camera, view: ViewKeypoints | None,
                 others: Sequence[ViewKeypoints], lifted: LiftedKeypoints, handedness: Handedness
                 ) -> ViewKeypoints | None:
    """A new detection in the window the other views' lift gives (turned upright by the projected wrist -> middle MCP),
    or another of the view's hands (`others`), kept when it lies nearer that projection than `view` does and within
    SECOND_LOOK_FRACTION of the projected hand's size of it; otherwise `view`."""
    expected = projected_keypoints(lifted, camera)
    if expected is None:
        return view
    crop = refined_crop(expected, handedness == "left")
    cx, cy = crop.center_px
    if not (-0.5 <= cx <= camera.width - 0.5 and -0.5 <= cy <= camera.height - 0.5):
        return view  # the hand is outside this view
    again = detect_view(model, image, [StartCrop(crop, False, "lifted"), StartCrop(crop, True, "lifted")], handedness)
    limit = SECOND_LOOK_FRACTION * max(float(np.ptp(expected, axis=0).max()), 1.0)
    found = [v for v in (again, *others) if v is not None and _median_distance(v, expected) < limit]
    if not found:
        return view
    nearest = min(found, key=lambda v: _median_distance(v, expected))
    if view is None or _median_distance(nearest, expected) < _median_distance(view, expected):
        return nearest
    return view


def _median_distance(view: ViewKeypoints, expected_px: np.ndarray) -> float:
    return float(np.median(np.linalg.norm(view.keypoints_px - expected_px, axis=1)))


def detect_frame(images: Sequence[np.ndarray], cameras: Sequence[Camera],
                 masks: Sequence[np.ndarray | None] | None = None, *,
                 handedness: Handedness = "right") -> LiftedKeypoints:
    """Detect and lift the hand of side `handedness` in one multi-view frame.

    Args:
        images: C (H, W, 3) uint8 RGB images in calibration order.
        cameras: the C cameras.
        masks: per view an (H, W) bool mask locating the hand (chroma key, HandSegNet) or None.
        handedness: which hand (a left hand is shown to the model mirrored). With several hands in view, the one of
            this side, the same hand in every view; with one hand in view, that hand whatever its side.
    Raises:
        DetectorInputError: fewer than 2 views, mismatched lists, malformed arrays.
        DetectorUnavailableError: model files missing or corrupt.
    """
    if handedness not in ("right", "left"):
        raise DetectorInputError(f"handedness must be 'right' or 'left', got {handedness!r}")
    mask_list = _check_inputs(images, cameras, masks)
    model, palms = landmark_model(), palm_detector()
    candidates = [view_hands(model, image, hand_searches(image, mask, palms), handedness)
                  for image, mask in zip(images, mask_list, strict=True)]
    return _lift_with_second_look(model, images, cameras, choose_hand(candidates, cameras, handedness), candidates,
                                  handedness)


def _lift_with_second_look(model: LandmarkModel, images: Sequence[np.ndarray], cameras: Sequence[Camera],
                           views: list[ViewKeypoints | None], candidates: Sequence[Sequence[ViewKeypoints]],
                           handedness: Handedness) -> LiftedKeypoints:
    """Lift one hand's views; views that found nothing, or a hand the others disagree with, look again where the
    others put it (`_second_look`), and the hand is lifted again where one changed."""
    lifted = lift(views, cameras)
    doubtful = [c for c, v in enumerate(views) if v is None or lifted.inliers[:, c].sum() < MIN_INLIER_KEYPOINTS]
    if doubtful and sum(v is not None for v in views) >= 2:
        changed = False
        for c in doubtful:
            others = [h for h in candidates[c] if h is not views[c]]
            again = _second_look(model, images[c], cameras[c], views[c], others, lifted, handedness)
            changed = changed or again is not views[c]
            views[c] = again
        if changed:
            lifted = lift(views, cameras)
    return lifted


def detect_frame_hands(images: Sequence[np.ndarray], cameras: Sequence[Camera],
                       masks: Sequence[np.ndarray | None] | None = None) -> list[tuple[Handedness | None,
                                                                                         LiftedKeypoints]]:
    """Every hand of one multi-view frame seen in two views or more, each lifted on its own: (its side, None where
    unclear; its lift), most views first. A detection belongs to one hand only (groups sharing one with a larger
    group are left out). Arguments and errors as `detect_frame`. Every detection is read as a right hand (the shown
    and mirrored readings are averaged either way); a hand's second look reads it as its side.
    """
    mask_list = _check_inputs(images, cameras, masks)
    model, palms = landmark_model(), palm_detector()
    candidates = [view_hands(model, image, hand_searches(image, mask, palms))
                  for image, mask in zip(images, mask_list, strict=True)]
    taken: set[tuple[int, int]] = set()
    out: list[tuple[Handedness | None, LiftedKeypoints]] = []
    for group in hand_groups(candidates, cameras):
        nodes = set(group.members.items())
        if len(nodes) < 2 or nodes & taken:
            continue
        taken |= nodes
        views: list[ViewKeypoints | None] = [candidates[c][group.members[c]] if c in group.members else None
                                             for c in range(len(cameras))]
        out.append((group.side, _lift_with_second_look(model, images, cameras, views, candidates,
                                                       group.side or "right")))
    return out


def detect_image(image: np.ndarray, box_px: Sequence[float] | None = None, *,
                 handedness: Handedness = "right") -> ViewKeypoints | None:
    """One photo, no calibration: the 21 keypoints of the hand of side `handedness`, or None when no hand is found.

    With several hands, the most present one the model reads as that side (`ViewKeypoints.right_score`); with one
    hand, or none of that side, the first found whatever its side (its `model_side` says which the model thinks).

    Args:
        image: (H, W, 3) uint8 RGB.
        box_px: optional x, y, width, height in pixels saying where the hand is (inside the image). The palm detector
            looks inside it first, then the box itself is tried at 4 quarter turns. Without it the palm detector
            searches the whole image, then the whole image's centred square is tried.
        handedness: the side looked for; every hand is read as that side (a left hand is shown mirrored).
    Raises:
        DetectorInputError: a malformed image or a box that is not inside it.
        DetectorUnavailableError: model files missing or corrupt.
    """
    return hand_of_side(detect_image_hands(image, box_px, handedness=handedness), handedness)


def detect_image_hands(image: np.ndarray, box_px: Sequence[float] | None = None, *,
                       handedness: Handedness = "right") -> list[ViewKeypoints]:
    """Every hand in one photo (see `detect_image`), in the order found, each read as side `handedness`."""
    image = check_image(image, "image")
    if handedness not in ("right", "left"):
        raise DetectorInputError(f"handedness must be 'right' or 'left', got {handedness!r}")
    height, width = image.shape[:2]
    model, palms = landmark_model(), palm_detector()
    if box_px is not None:
        x, y, w, h = check_box(box_px, width, height)
        box = Crop((x + w / 2 - 0.5, y + h / 2 - 0.5), max(w, h) * BOX_SCALE)
        found = palms.detect(image, box, max_palms=MAX_HANDS)
        searches = [[StartCrop(p.crop, False, "box+palm") for p in found[:1]] + [StartCrop(box, True, "box")]]
        searches += [[StartCrop(p.crop, False, "box+palm")] for p in found[1:]]
    else:
        searches = hand_searches(image, None, palms) or [[]]
        searches[0] = [*searches[0], StartCrop(Crop(((width - 1) / 2, (height - 1) / 2), float(min(width, height))),
                                                True, "image")]
    return view_hands(model, image, searches, handedness)


def check_box(box_px: Sequence[float], width: int, height: int) -> tuple[float, float, float, float]:
    """x, y, w, h of a box inside a width x height image (edges at 0 and width), or DetectorInputError saying why."""
    values = [float(v) for v in box_px]
    if len(values) != 4 or not all(np.isfinite(values)):
        raise DetectorInputError(f"a box is 4 finite numbers x, y, width, height; got {list(box_px)}")
    x, y, w, h = values
    if w <= 0 or h <= 0:
        raise DetectorInputError(f"box width and height must be positive, got {w:g} x {h:g}")
    if x < 0 or y < 0 or x + w > width or y + h > height:
        raise DetectorInputError(f"box {x:g},{y:g},{w:g},{h:g} is not inside the {width}x{height} image")
    return x, y, w, h
