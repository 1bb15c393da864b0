"""Skinning weights (V, 16) of the built-in hand from distances to bone segments.

Each joint owns bone segments: the wrist owns the four metacarpals (wrist -> finger MCP) and the forearm
stub; every other joint owns the segment to its child joint (or to the fingertip). A vertex's weights
are a soft-min over its distances to all segments (temperature `softness_m`), summed per joint, then
smoothed over the mesh graph. The soft transition spans about sqrt(2 r softness) on each side of a joint
of radius r, which keeps bent joints round instead of pinched.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from workers.handmodel.builtin.skeleton import FINGER_JOINTS, Skeleton
from workers.handmodel.keypoints import NUM_JOINTS

if TYPE_CHECKING:
    import scipy.sparse as sp


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance (N,) from points p (N, 3) to the segment a-b (metres)."""
    e = b - a
    t = np.clip(((p - a) @ e) / float(e @ e), 0.0, 1.0)
    return np.linalg.norm(p - a - t[:, None] * e, axis=1)


def bone_segments(skel: Skeleton) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """(joint id, start (3,), end (3,)) of every bone segment of the rest skeleton."""
    size = skel.proportions.hand_length_m / 0.19 * skel.proportions.size
    segs: list[tuple[int, np.ndarray, np.ndarray]] = []
    wrist = skel.joints[0]
    segs.append((0, wrist, wrist - np.array([0.03 * size, 0.0, 0.0])))
    for f in range(1, 5):
        segs.append((0, wrist, skel.joints[FINGER_JOINTS[f][0]]))
    for f in range(5):
        chain = skel.chain(f)
        for k, j in enumerate(FINGER_JOINTS[f]):
            segs.append((j, chain[k], chain[k + 1]))
    return segs


def vertex_adjacency(faces: np.ndarray, num_vertices: int) -> sp.csr_matrix:
    """Row-normalised (V, V) adjacency of the mesh graph (uniform umbrella operator)."""
    # deferred: scipy.sparse takes ~0.5 s to import; only building the hand needs it, not loading it from its cache
    import scipy.sparse as sp

    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(num_vertices, num_vertices)).tocsr()
    adj.data[:] = 1.0
    return sp.diags(1.0 / np.asarray(adj.sum(axis=1)).ravel()) @ adj


def skinning_weights(vertices: np.ndarray, faces: np.ndarray, skel: Skeleton, *,
                     softness_m: float = 0.0022, smooth_iterations: int = 4,
                     prune_below: float = 0.01) -> np.ndarray:
    """Skinning weights (V, 16) for rest vertices (V, 3) metres; rows sum to 1, entries >= 0."""
    segs = bone_segments(skel)
    dist = np.stack([point_segment_distance(vertices, a, b) for _, a, b in segs], axis=1)  # (V, S)
    raw = np.exp(-(dist - dist.min(axis=1, keepdims=True)) / softness_m)
    w = np.zeros((vertices.shape[0], NUM_JOINTS))
    for s, (j, _, _) in enumerate(segs):
        w[:, j] += raw[:, s]
    w /= w.sum(axis=1, keepdims=True)
    avg = vertex_adjacency(faces, vertices.shape[0])
    for _ in range(smooth_iterations):
        w = 0.5 * w + 0.5 * (avg @ w)
    w[w < prune_below] = 0.0
    return w / w.sum(axis=1, keepdims=True)
