"""Shape blend shapes (V, 3, 10) of the built-in hand by a skeleton-driven space warp.

Changing the proportions moves every joint and rescales every bone (along its axis and across it).
Each rest vertex follows the bones it is skinned to: v' = sum_j w_j (o'_j + R_j diag(s'_j / s_j) R_j^T
(v - o_j)), with o_j, R_j the joint's rest centre and frame. The template keeps its connectivity, so
vertex correspondence holds. Direction k is the central difference of the warp over +-1 standard
deviation of its proportion (beta = 1 is about one SD of the adult population, like MANO's PCA betas).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from workers.handmodel.builtin.skeleton import HandProportions, Skeleton, build_skeleton


def _fingers(p: HandProportions, scales: tuple[float, float, float, float]) -> HandProportions:
    return replace(p, finger_length=tuple(a * b for a, b in zip(p.finger_length, scales, strict=True)))


# (name, change of the proportions for beta = +1 / -1 given the signed fraction s).
SHAPE_DIRECTIONS: tuple[tuple[str, float, Callable[[HandProportions, float], HandProportions]], ...] = (
    ("size", 0.05, lambda p, s: replace(p, size=p.size * (1 + s))),
    ("palm_breadth", 0.05, lambda p, s: replace(p, palm_breadth=p.palm_breadth * (1 + s))),
    ("finger_length", 0.045, lambda p, s: _fingers(p, (1 + s,) * 4)),
    ("finger_thickness", 0.07, lambda p, s: replace(p, finger_thickness=p.finger_thickness * (1 + s))),
    ("palm_length", 0.045, lambda p, s: replace(p, palm_length=p.palm_length * (1 + s))),
    ("thumb_length", 0.05, lambda p, s: replace(p, thumb_length=p.thumb_length * (1 + s))),
    ("palm_thickness", 0.08, lambda p, s: replace(p, palm_thickness=p.palm_thickness * (1 + s))),
    ("index_ring_ratio", 0.03, lambda p, s: _fingers(p, (1 + s, 1.0, 1 - s, 1.0))),
    ("pinky_length", 0.06, lambda p, s: _fingers(p, (1.0, 1.0, 1.0, 1 + s))),
    ("slenderness", 0.04, lambda p, s: replace(_fingers(p, (1 + s,) * 4), palm_breadth=p.palm_breadth * (1 - s),
                                               finger_thickness=p.finger_thickness * (1 - s))),
)
SHAPE_NAMES: tuple[str, ...] = tuple(name for name, _, _ in SHAPE_DIRECTIONS)


def warp_vertices(vertices: np.ndarray, weights: np.ndarray, rest: Skeleton, new: Skeleton) -> np.ndarray:
    """Move rest vertices (V, 3) with the skeleton change rest -> new, blended by weights (V, 16)."""
    out = np.zeros_like(vertices)
    for j in range(rest.joints.shape[0]):
        R = rest.frames[j]
        S = np.diag(new.scales[j] / rest.scales[j])
        A = R @ S @ R.T
        moved = new.joints[j] + (vertices - rest.joints[j]) @ A.T
        out += weights[:, j : j + 1] * moved
    return out


def shape_directions(vertices: np.ndarray, weights: np.ndarray, rest: Skeleton) -> np.ndarray:
    """shapedirs (V, 3, 10): metres per unit beta, in SHAPE_NAMES order."""
    dirs = np.zeros((vertices.shape[0], 3, len(SHAPE_DIRECTIONS)))
    for k, (_, sd, change) in enumerate(SHAPE_DIRECTIONS):
        plus = build_skeleton(change(rest.proportions, sd))
        minus = build_skeleton(change(rest.proportions, -sd))
        dirs[:, :, k] = 0.5 * (warp_vertices(vertices, weights, rest, plus)
                               - warp_vertices(vertices, weights, rest, minus))
    return dirs
