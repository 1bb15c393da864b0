"""Closed triangle mesh of an implicit surface: marching cubes, decimation, projection, smoothing.

Quadric decimation alone leaves long slivers along the (nearly cylindrical) fingers, which bend badly
under skinning. So the surface is meshed with a faint periodic ripple added to the distance field; the
decimator keeps vertices on the ripple's crests and troughs, i.e. spread evenly over the whole hand,
and afterwards each vertex is projected back onto the smooth surface (Newton steps along the field's
gradient) and the mesh is lightly Taubin-smoothed. Everything is deterministic.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

logger = logging.getLogger(__name__)

SdfFn = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class MeshingSettings:
    """Meshing knobs (metres)."""

    voxel_m: float = 0.0011
    ripple_period_m: float = 0.0085
    ripple_amplitude_m: float = 0.0004
    target_vertices: int = 1500
    taubin_iterations: int = 6
    margin_m: float = 0.006


def ripple(p: np.ndarray, period_m: float) -> np.ndarray:
    """A 3D periodic pattern (N,) in [-1, 1] that shows as an even grid of bumps on any surface."""
    w = 2.0 * np.pi / period_m
    return (np.sin(w * p[:, 0]) * np.sin(w * p[:, 1]) + np.sin(w * p[:, 1]) * np.sin(w * p[:, 2])
            + np.sin(w * p[:, 2]) * np.sin(w * p[:, 0])) / 3.0


def sdf_on_grid(sdf: SdfFn, lo: np.ndarray, hi: np.ndarray, voxel_m: float,
                extra: SdfFn | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Evaluate sdf (+ extra) on a regular grid; returns (volume (nx, ny, nz), origin (3,))."""
    n = np.ceil((hi - lo) / voxel_m).astype(int) + 1
    axes = [lo[i] + voxel_m * np.arange(n[i]) for i in range(3)]
    vol = np.empty(tuple(n), dtype=np.float64)
    yy, zz = np.meshgrid(axes[1], axes[2], indexing="ij")
    for i, x in enumerate(axes[0]):  # slab by slab keeps memory small
        pts = np.stack([np.full(yy.size, x), yy.ravel(), zz.ravel()], axis=1)
        val = sdf(pts)
        if extra is not None:
            val = val + extra(pts)
        vol[i] = val.reshape(yy.shape)
    return vol, lo


def project_to_surface(sdf: SdfFn, v: np.ndarray, steps: int = 4, eps: float = 1e-5) -> np.ndarray:
    """Move points (N, 3) onto the zero level of sdf by Newton steps along the numerical gradient."""
    v = v.copy()
    offsets = np.eye(3) * eps
    for _ in range(steps):
        d = sdf(v)
        grad = np.stack([(sdf(v + o) - sdf(v - o)) / (2 * eps) for o in offsets], axis=1)
        g2 = np.maximum(np.sum(grad * grad, axis=1), 1e-12)
        v -= (d / g2)[:, None] * grad
    return v


def taubin(v: np.ndarray, faces: np.ndarray, iterations: int, lam: float = 0.5,
           mu: float = -0.53) -> np.ndarray:
    """Taubin lambda/mu smoothing with uniform umbrella weights; returns new vertices (V, 3)."""

    nv = v.shape[0]
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(nv, nv)).tocsr()
    adj.data[:] = 1.0
    deg = np.asarray(adj.sum(axis=1)).ravel()
    avg = sp.diags(1.0 / deg) @ adj
    out = v.copy()
    for _ in range(iterations):
        out = out + lam * (avg @ out - out)
        out = out + mu * (avg @ out - out)
    return out


def mesh_implicit(sdf: SdfFn, lo: np.ndarray, hi: np.ndarray,
                  settings: MeshingSettings | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closed, consistently wound (outward, counter-clockwise) mesh of {sdf = 0} inside the box lo..hi.

    Returns (vertices (V, 3) float64 metres, faces (F, 3) int64).
    """
    # deferred: meshing runs when the hand is generated, never when it is loaded from the cache (the API)
    import fast_simplification
    import trimesh
    from skimage.measure import marching_cubes

    s = settings or MeshingSettings()
    lo = np.asarray(lo, dtype=np.float64) - s.margin_m
    hi = np.asarray(hi, dtype=np.float64) + s.margin_m
    vol, origin = sdf_on_grid(sdf, lo, hi, s.voxel_m,
                              extra=lambda p: s.ripple_amplitude_m * ripple(p, s.ripple_period_m))
    verts, faces, _, _ = marching_cubes(vol, level=0.0, spacing=(s.voxel_m,) * 3)
    verts = verts.astype(np.float64) + origin
    faces = faces.astype(np.int64)
    logger.debug("marching cubes: %d vertices, %d faces", len(verts), len(faces))
    ratio = 1.0 - 2.0 * s.target_vertices / len(faces)
    v_dec, f_dec = fast_simplification.simplify(verts.astype(np.float32), faces.astype(np.int32),
                                                target_reduction=ratio)
    v_dec = np.asarray(v_dec, dtype=np.float64)
    f_dec = np.asarray(f_dec, dtype=np.int64)
    mesh = trimesh.Trimesh(v_dec, f_dec, process=True, validate=False)
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    for _ in range(2):
        v = project_to_surface(sdf, v)
        v = taubin(v, f, s.taubin_iterations)
    v = project_to_surface(sdf, v)
    mesh = trimesh.Trimesh(v, f, process=False, validate=False)
    if mesh.volume < 0:
        f = f[:, ::-1].copy()
    logger.debug("decimated mesh: %d vertices, %d faces", len(v), len(f))
    return v, f
