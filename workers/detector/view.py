"""One view's 21 keypoints from the landmark model: crop, orientation, mirroring, and per-keypoint scores.

The search per view: the start crop (from a mask, the palm detector, or the other views' lift) is shown at 4
rotations and the one with the highest presence is kept; its keypoints then give a tighter crop turned so wrist ->
middle MCP points up, which is run again, as shown and mirrored. The two refined runs are averaged (weighted by their
presence); the refined crop replaces the start crop only where its presence is not lower. `hand_searches` gives
one list of start crops per hand that may be in view (palms, mask blobs); hands.py runs them all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from workers.detector.crops import Crop, mask_windows, upright_rotation
from workers.detector.landmark_model import LandmarkModel, LandmarkOutput
from workers.detector.palm import PalmDetector
from workers.detector.types import Handedness, ViewKeypoints

START_ROTATIONS_RAD = (0.0, math.pi / 2, math.pi, 3 * math.pi / 2)
# Side of the refined crop over the longer side of the keypoints' box in the turned frame (MediaPipe uses 2.0
# around palm landmarks; the whole hand's box needs less).
REFINED_SCALE = 1.6
# Per-keypoint score: presence times a Gaussian of the disagreement between the shown and mirrored runs, in units of
# this fraction of the hand's size (the longer side of the keypoints' box).
AGREEMENT_FRACTION = 0.05
MIN_PRESENCE = 0.2
ACCEPT_PRESENCE = 0.5
# Side of the window around a mask's blob over the blob's longer side.
MASK_SCALE = 1.1
# At most this many hands are looked for per view (palms, mask blobs).
MAX_HANDS = 4


@dataclass(frozen=True)
class _Run:
    crop: Crop
    output: LandmarkOutput

    @property
    def keypoints_px(self) -> np.ndarray:
        return self.crop.to_image(self.output.keypoints_crop)


def _run(model: LandmarkModel, image: np.ndarray, crop: Crop) -> _Run:
    return _Run(crop, model.run(crop.extract(image)))


def refined_crop(keypoints_px: np.ndarray, mirrored: bool, scale: float = REFINED_SCALE) -> Crop:
    """The square crop around keypoints (21, 2), turned so wrist -> middle MCP points up, `scale` x their box."""
    rotation = upright_rotation(keypoints_px[0], keypoints_px[9])
    base = Crop((0.0, 0.0), 1.0, rotation, mirrored, size=1)
    local = base.to_crop(keypoints_px)  # in the turned frame, image-pixel units
    lo, hi = local.min(axis=0), local.max(axis=0)
    center = base.to_image((lo + hi) / 2)
    side = float(max(hi - lo)) * scale
    return Crop((float(center[0]), float(center[1])), max(side, 8.0), rotation, mirrored)


@dataclass(frozen=True)
class StartCrop:
    """A window to try first; `search` asks for all 4 quarter turns of it (the palm detector's come turned already)."""

    crop: Crop
    search: bool
    source: str


def hand_searches(image: np.ndarray, mask: np.ndarray | None, palms: PalmDetector | None,
                  max_hands: int = MAX_HANDS) -> list[list[StartCrop]]:
    """Windows to look for hands in: one list of windows per search (`detect_view` tries a list's windows in order
    until one shows a hand), the first search the one-hand search of before (#36), then one per further palm or mask
    blob. Empty where there is nowhere to look.

    A chroma-key mask continues into the forearm and sleeve, so its box is much larger than the hand (at 320 px the
    hand was ~1/4 of it and the landmark model found nothing there): the palm detector looks inside each large blob's
    box first, then the box itself is tried (right for hand-only masks). Without a mask the palm detector sees the
    whole image. (pipeline.py gives a view a second look from the other views' lift.)
    """
    searches: list[list[StartCrop]] = []
    extra: list[list[StartCrop]] = []
    windows = mask_windows(mask, MASK_SCALE, max_count=max_hands) if mask is not None else []
    for window in windows:
        box = Crop((window[0], window[1]), window[2])
        found = palms.detect(image, box, max_palms=max_hands) if palms is not None else []
        searches.append([StartCrop(p.crop, False, "mask+palm") for p in found[:1]] + [StartCrop(box, True, "mask")])
        extra += [[StartCrop(p.crop, False, "mask+palm")] for p in found[1:]]
    if not windows and palms is not None:
        found = palms.detect(image, max_palms=max_hands)
        searches += [[StartCrop(p.crop, False, "palm")] for p in found]
    return searches + extra


def detect_view(model: LandmarkModel, image: np.ndarray, starts: list[StartCrop],
                handedness: Handedness = "right") -> ViewKeypoints | None:
    """Keypoints of the hand in `image` (H, W, 3) uint8 RGB; None when no start window shows a hand.

    Args:
        starts: windows tried in order until one shows a hand with presence >= ACCEPT_PRESENCE (the best of all
            is kept otherwise); their `mirrored` flag is overridden by `handedness`.
    Returns:
        ViewKeypoints with scores = presence * exp(-0.5 (d_k / (AGREEMENT_FRACTION * hand size))^2), d_k the distance
        in pixels between keypoint k of the shown and of the mirrored refined run (the model has no per-keypoint
        output; where the two readings of the same pixels disagree, the keypoint is ambiguous).
    """
    mirrored = handedness == "left"
    best: _Run | None = None
    for start in starts:
        turns = START_ROTATIONS_RAD if start.search else (0.0,)
        for t in turns:
            c = start.crop
            run = _run(model, image, Crop(c.center_px, c.side_px, c.rotation_rad + t, mirrored))
            if best is None or run.output.presence > best.output.presence:
                best = run
        if best is not None and best.output.presence >= ACCEPT_PRESENCE:
            break
    if best is None or best.output.presence < MIN_PRESENCE:
        return None
    crop = refined_crop(best.keypoints_px, mirrored)
    shown = _run(model, image, crop)
    if shown.output.presence < best.output.presence:
        shown, crop = best, best.crop
    flipped = _run(model, image, Crop(crop.center_px, crop.side_px, crop.rotation_rad, not mirrored))
    w_shown, w_flipped = shown.output.presence, flipped.output.presence
    kp_shown, kp_flipped = shown.keypoints_px, flipped.keypoints_px
    keypoints = (w_shown * kp_shown + w_flipped * kp_flipped) / max(w_shown + w_flipped, 1e-9)
    hand_size = max(float(np.ptp(keypoints, axis=0).max()), 1.0)
    disagreement = np.linalg.norm(kp_shown - kp_flipped, axis=1)
    presence = shown.output.presence
    scores = presence * np.exp(-0.5 * (disagreement / (AGREEMENT_FRACTION * hand_size)) ** 2)
    # The model's handedness output reads the crop as shown: a mirrored crop shows the other hand. Both runs vote.
    plain, mirror = (flipped, shown) if shown.crop.mirrored else (shown, flipped)
    right_score = 0.5 * (plain.output.right_score + 1.0 - mirror.output.right_score)
    return ViewKeypoints(keypoints_px=keypoints, scores=np.clip(scores, 0.0, 1.0), presence=float(presence),
                         handedness=handedness, box_px=crop.bounds_px(), rotation_rad=float(crop.rotation_rad),
                         right_score=float(np.clip(right_score, 0.0, 1.0)))
