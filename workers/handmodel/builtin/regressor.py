"""Joint regressor (16, V) of the built-in hand: each joint centre as a convex mix of nearby vertices.

For every joint, the vertices of a thin ring around it (on the skin of that joint) get Gaussian prior
weights; non-negative least squares then adjusts them so the weighted mean hits the rest joint centre
exactly. Because the ring follows the skin, the regressed joints follow shape changes (blend shapes).
"""

from __future__ import annotations

import numpy as np

from workers.handmodel.builtin.skeleton import Skeleton
from workers.handmodel.keypoints import NUM_JOINTS


def _ring(vertices: np.ndarray, weights: np.ndarray, skel: Skeleton, j: int) -> tuple[np.ndarray, np.ndarray]:
    """(ids, prior weights) of the vertices around joint j's centre."""
    centre = skel.joints[j]
    axis = skel.frames[j][:, 0]
    size = skel.proportions.hand_length_m / 0.19 * skel.proportions.size
    rel = vertices - centre
    along = rel @ axis
    radial = np.linalg.norm(rel - along[:, None] * axis, axis=1)
    if j == 0:  # the wrist: the skin ring of the stub at the wrist crease
        band, reach = 0.006 * size, 0.05 * size
        owner = weights[:, 0] > 0.5
    else:
        band, reach = 0.004 * size, 0.03 * size
        parent_like = weights[:, j] + (weights[:, j - 1] if j not in (1, 4, 7, 10, 13) else weights[:, 0])
        owner = parent_like > 0.6
    sel = np.flatnonzero((np.abs(along) < band) & (radial < reach) & owner)
    if sel.size < 6:  # fall back to the nearest vertices
        sel = np.argsort(np.linalg.norm(rel, axis=1))[:12]
    prior = np.exp(-0.5 * (along[sel] / band) ** 2)
    return sel, prior / prior.sum()


def joint_regressor(vertices: np.ndarray, weights: np.ndarray, skel: Skeleton) -> np.ndarray:
    """Dense (16, V) regressor: rows >= 0, sum to 1, and J_regressor @ vertices == skel.joints at rest."""
    # deferred: scipy.optimize takes 1-2 s to import; only building the hand needs it, not loading it from its
    # cache (the API's first review page after a start paid for it)
    from scipy.optimize import nnls

    reg = np.zeros((NUM_JOINTS, vertices.shape[0]))
    for j in range(NUM_JOINTS):
        ids, prior = _ring(vertices, weights, skel, j)
        big = 1000.0
        A = np.concatenate([big * np.vstack([vertices[ids].T, np.ones((1, ids.size))]),
                            np.eye(ids.size) * 0.05])
        b = np.concatenate([big * np.append(skel.joints[j], 1.0), 0.05 * prior])
        w, _ = nnls(A, b, maxiter=50 * ids.size)
        reg[j, ids] = w / w.sum()
    return reg
