"""Which points a mesh hides from each camera, by casting the ray from the camera's centre to each point.

A ray test instead of a z-buffer: only a few points per view are asked about, the answer does not depend on
the image size, and lens distortion does not matter (the ray to a world point is the same with or without it).
"""

from __future__ import annotations

import numpy as np

from workers.geometry.camera import Camera


def _nearest_hit(origin: np.ndarray, targets: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(N,) fraction of the way from `origin` to each target at which the segment first meets a triangle
    (Moller-Trumbore), inf where it meets none.

    Args:
        origin: (3,) metres. targets: (N, 3) metres. tri: (F, 3, 3) triangle corners, metres.
    """
    d = targets - origin  # (N, 3): the segment, parameter s in [0, 1]
    e1 = tri[:, 1] - tri[:, 0]  # (F, 3)
    e2 = tri[:, 2] - tri[:, 0]
    p = np.cross(d[:, None, :], e2[None])  # (N, F, 3)
    det = np.einsum("nfk,fk->nf", p, e1)
    ok = np.abs(det) > 1e-15
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tvec = origin - tri[:, 0]  # (F, 3)
    u = np.einsum("nfk,fk->nf", p, tvec) * inv
    q = np.cross(tvec, e1)  # (F, 3)
    v = np.einsum("nk,fk->nf", d, q) * inv
    s = np.einsum("fk,fk->f", e2, q)[None] * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (s > 0)
    return np.where(hit, s, np.inf).min(axis=1)


def hidden_by_mesh(points_world: np.ndarray, vertices_world: np.ndarray, faces: np.ndarray, cameras: list[Camera],
                   tolerance_m: np.ndarray) -> np.ndarray:
    """(C, N) bool: the mesh's surface lies between camera c and point n by more than tolerance_m[n].

    A point inside the mesh (a joint under the skin) is behind its own skin by the skin's depth there: the
    tolerance (workers.synth.visibility.skin_depth_tolerance_m) keeps that from counting as hidden.

    Args:
        points_world: (N, 3) metres, world frame.
        vertices_world: (V, 3) metres, world frame. faces: (F, 3) vertex indices.
        cameras: C cameras (R world -> camera, t metres).
        tolerance_m: (N,) metres.
    """
    points = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    tri = np.asarray(vertices_world, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]  # (F, 3, 3)
    tolerance = np.broadcast_to(np.asarray(tolerance_m, dtype=np.float64), (len(points),))
    out = np.zeros((len(cameras), len(points)), dtype=bool)
    for c, cam in enumerate(cameras):
        centre = -cam.R.T @ cam.t
        length = np.linalg.norm(points - centre, axis=1)
        s = _nearest_hit(centre, points, tri)
        out[c] = np.isfinite(s) & ((1.0 - s) * length > tolerance)
    return out
