"""Mesh sanity checks used by the tests and by anyone who changes the generator.

`count_self_intersections` is a simple, exact-enough test: two triangles of a closed mesh intersect
(away from shared vertices) iff an edge of one crosses the other; candidate pairs come from a k-d tree
over triangle centroids, and each (edge, triangle) pair is tested with Moller-Trumbore.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def count_self_intersections(vertices: np.ndarray, faces: np.ndarray, eps: float = 1e-9) -> int:
    """Number of (edge, triangle) crossings between edges and triangles that share no vertex.

    vertices (V, 3) metres, faces (F, 3) int. 0 for a mesh without self-intersections.
    """
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]),
                              axis=1), axis=0)
    tri = vertices[faces]  # (F, 3, 3)
    centroids = tri.mean(axis=1)
    radius = np.linalg.norm(tri - centroids[:, None], axis=2).max()
    p0, p1 = vertices[edges[:, 0]], vertices[edges[:, 1]]
    half = 0.5 * np.linalg.norm(p1 - p0, axis=1).max()
    pairs = cKDTree(centroids).query_ball_point(0.5 * (p0 + p1), r=radius + half)
    e_idx = np.repeat(np.arange(len(edges)), [len(p) for p in pairs])
    f_idx = np.concatenate([np.asarray(p, dtype=np.int64) for p in pairs])
    share = (faces[f_idx] == edges[e_idx, 0:1]).any(axis=1) | (faces[f_idx] == edges[e_idx, 1:2]).any(axis=1)
    e_idx, f_idx = e_idx[~share], f_idx[~share]
    orig, d = p0[e_idx], p1[e_idx] - p0[e_idx]
    a, b, c = tri[f_idx, 0], tri[f_idx, 1], tri[f_idx, 2]
    e1, e2 = b - a, c - a
    pvec = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, pvec)
    ok = np.abs(det) > eps * eps
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tvec = orig - a
    u = np.einsum("ij,ij->i", tvec, pvec) * inv
    qvec = np.cross(tvec, e1)
    v = np.einsum("ij,ij->i", d, qvec) * inv
    t = np.einsum("ij,ij->i", e2, qvec) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)
    return int(hit.sum())
