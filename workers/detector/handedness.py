"""Which side a hand is: from its lifted 3D keypoints (chirality) and from the landmark model's handedness output.

Chirality: the thumb lies on the palm's side and the fingers curl towards it. With n = (index MCP - wrist) x
(pinky MCP - wrist), a right hand's thumb tip and fingertips lie on +n's side, a left hand's on -n's. Measured on
200 poses of the built-in hand's pose sampler per side: the thumb tip alone on the right side in 100 % of right and
99.5 % of left poses. The model's handedness from single views is much weaker on the built-in hand's renders (a right
hand read right in 3 of 7 views of one frame), so a lifted hand's chirality decides where it is clear.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from workers.detector.types import Handedness, LiftedKeypoints, ViewKeypoints

WRIST, THUMB_TIP, INDEX_MCP, MIDDLE_MCP, PINKY_MCP = 0, 4, 5, 9, 17
FINGER_MCP_TIP = ((5, 8), (9, 12), (13, 16), (17, 20))
# |chirality| below this (in wrist -> middle MCP lengths) decides nothing: a flat hand, its thumb in the palm's plane.
CHIRALITY_MARGIN = 0.1


def chirality(points_world: np.ndarray) -> float:
    """(21, 3) keypoints (metres, NaN rows where not lifted) -> > 0 for a right hand, < 0 for a left one: the thumb
    tip's and the mean fingertip curl's offsets along the palm's normal (index MCP - wrist) x (pinky MCP - wrist),
    in units of the wrist -> middle MCP length. NaN where the wrist, the MCPs or the thumb tip were not lifted."""
    p = np.asarray(points_world, dtype=np.float64)
    if not np.isfinite(p[[WRIST, THUMB_TIP, INDEX_MCP, MIDDLE_MCP, PINKY_MCP]]).all():
        return float("nan")
    normal = np.cross(p[INDEX_MCP] - p[WRIST], p[PINKY_MCP] - p[WRIST])
    size = float(np.linalg.norm(p[MIDDLE_MCP] - p[WRIST]))
    if np.linalg.norm(normal) < 1e-12 or size < 1e-9:
        return float("nan")
    normal /= np.linalg.norm(normal)
    curls = [float((p[tip] - p[mcp]) @ normal) for mcp, tip in FINGER_MCP_TIP if np.isfinite(p[[mcp, tip]]).all()]
    curl = float(np.mean(curls)) if curls else 0.0
    return (float((p[THUMB_TIP] - p[WRIST]) @ normal) + curl) / size


def model_right_score(views: Iterable[ViewKeypoints | None]) -> float:
    """The views' own handedness (`ViewKeypoints.right_score`) averaged with their presence as weights; NaN where no
    view has one."""
    pairs = [(v.right_score, v.presence) for v in views if v is not None and np.isfinite(v.right_score)]
    weight = sum(w for _, w in pairs)
    return float(sum(s * w for s, w in pairs) / weight) if pairs and weight > 0 else float("nan")


def side_of(points_world: np.ndarray | None, views: Sequence[ViewKeypoints | None]) -> Handedness | None:
    """The side of one hand: its chirality where lifted and clear, else the views' handedness vote; None where
    neither says."""
    if points_world is not None:
        c = chirality(points_world)
        if np.isfinite(c) and abs(c) >= CHIRALITY_MARGIN:
            return "right" if c > 0 else "left"
    score = model_right_score(views)
    if not np.isfinite(score):
        return None
    return "right" if score >= 0.5 else "left"


def lifted_side(lifted: LiftedKeypoints) -> Handedness | None:
    """The side of a frame's lifted hand (`side_of` its lifted keypoints and views)."""
    return side_of(lifted.points_world, lifted.views)


def side_disagreement(sides: Iterable[Handedness | None], declared: Handedness, *, min_frames: int = 3,
                      fraction: float = 2 / 3) -> str | None:
    """A sentence where the frames of a sequence say its hand is the other side than `declared` (the side the
    detector was asked for: the capture's, unless a job named one), at least `min_frames` frames deciding and
    `fraction` of them the other side; else None."""
    decided = [s for s in sides if s is not None]
    other = sum(s != declared for s in decided)
    if len(decided) < min_frames or other < fraction * len(decided):
        return None
    return (f"the detected hand looks like a {'left' if declared == 'right' else 'right'} hand in {other} of "
            f"{len(decided)} frames, but a {declared} hand was asked for: check the capture's hand side")
