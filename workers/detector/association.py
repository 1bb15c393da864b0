"""Several hands per view -> the same hand in every view: groups of detections consistent under the cameras'
epipolar geometry, and the group of the side asked for.

Two detections in two views are of one hand when the median symmetric epipolar distance of their 21 keypoints is
below EPIPOLAR_FRACTION of the hands' size in pixels. A group grows from every detection as seed, adding the
detection of another view that agrees with the most members (at least half of them). Each group of two or more
views is lifted and its side read from the lift's chirality (thumb and finger curl on the palm's side), where that is
unclear from the views' handedness vote (workers/detector/handedness.py). The group chosen: one seen in two views
or more before one seen once, then of the side asked for, then the one seen in most views, then the most present.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from workers.detector.handedness import side_of
from workers.detector.hands import hand_size_px
from workers.detector.lifting import lift
from workers.detector.types import Handedness, ViewKeypoints
from workers.geometry.camera import Camera
from workers.geometry.epipolar import symmetric_epipolar_distances

# Median epipolar distance of two views' keypoints over the hands' mean size (px) below which they are one hand. The
# detector's own error is ~6 % of the hand's box (lifting.py's reprojection threshold is 12 %).
EPIPOLAR_FRACTION = 0.15

Node = tuple[int, int]  # (view, candidate index in that view)


@dataclass(frozen=True)
class HandGroup:
    """One hand across views: view -> its detection's index there, and the hand's side (None: unknown)."""

    members: dict[int, int]
    side: Handedness | None
    presence: float


def _pair_distances(candidates: Sequence[Sequence[ViewKeypoints]], cameras: Sequence[Camera]
                    ) -> dict[tuple[Node, Node], float]:
    """(a, b) -> median symmetric epipolar distance over the hands' mean size, for detections of different views."""
    out: dict[tuple[Node, Node], float] = {}
    for a in range(len(cameras)):
        for b in range(a + 1, len(cameras)):
            for i, ha in enumerate(candidates[a]):
                for j, hb in enumerate(candidates[b]):
                    d = symmetric_epipolar_distances(ha.keypoints_px, hb.keypoints_px, cameras[a], cameras[b])
                    size = 0.5 * (hand_size_px(ha) + hand_size_px(hb))
                    out[(a, i), (b, j)] = out[(b, j), (a, i)] = float(np.median(d)) / size
    return out


def hand_groups(candidates: Sequence[Sequence[ViewKeypoints]], cameras: Sequence[Camera]) -> list[HandGroup]:
    """Every distinct group of mutually consistent detections (one per view at most), largest first."""
    nodes = [(c, i) for c, hands in enumerate(candidates) for i in range(len(hands))]
    distance = _pair_distances(candidates, cameras)
    seen: set[frozenset[Node]] = set()
    groups: list[HandGroup] = []
    for seed in nodes:
        members: dict[int, int] = {seed[0]: seed[1]}
        while True:
            best: tuple[int, float, Node] | None = None
            for node in nodes:
                if node[0] in members:
                    continue
                ds = [distance[(c, i), node] for c, i in members.items()]
                agree = sum(d < EPIPOLAR_FRACTION for d in ds)
                if agree == 0 or 2 * agree < len(members):
                    continue
                key = (agree, -float(np.mean(ds)), node)
                if best is None or key[:2] > best[:2]:
                    best = key
            if best is None:
                break
            members[best[2][0]] = best[2][1]
        key_set = frozenset(members.items())
        if key_set in seen:
            continue
        seen.add(key_set)
        views: list[ViewKeypoints | None] = [None] * len(cameras)
        for c, i in members.items():
            views[c] = candidates[c][i]
        points = lift(views, cameras).points_world if len(members) >= 2 else None
        groups.append(HandGroup(members, side_of(points, views),
                                float(sum(candidates[c][i].presence for c, i in members.items()))))
    groups.sort(key=lambda g: (len(g.members), g.presence), reverse=True)
    return groups


def choose_hand(candidates: Sequence[Sequence[ViewKeypoints]], cameras: Sequence[Camera],
                handedness: Handedness) -> list[ViewKeypoints | None]:
    """Per view the detection of the hand of side `handedness` (None where it has none), consistent over the views.

    Views with one detection each are kept as they are (one hand in view: the one-hand detector of before).
    """
    if all(len(hands) <= 1 for hands in candidates):
        return [hands[0] if hands else None for hands in candidates]
    groups = hand_groups(candidates, cameras)
    best = max(groups, key=lambda g: (len(g.members) >= 2, g.side == handedness, len(g.members), g.presence))
    return [candidates[c][best.members[c]] if c in best.members else None for c in range(len(cameras))]
