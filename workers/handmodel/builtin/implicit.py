"""Signed distance (approximate) of the built-in hand: smooth union of simple primitives.

Negative inside, metres, rest frame of `skeleton.py`. Fingers are round cones (capsules with varying
radius) of elliptical cross-section; the palm is a polygonal sheet thickened by a radius that varies
along the hand; the wrist stub is a rounded elliptic cylinder; thenar and hypothenar are ellipsoids.
Inigo Quilez's primitives (round cone, polynomial smooth minimum), written anew in numpy.
"""

from __future__ import annotations

import numpy as np

from workers.handmodel.builtin.skeleton import DEPTH_RATIO, FINGER_JOINTS, Skeleton


def smin(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum with blend radius `k` (metres); min(a, b) where |a - b| >= k."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b * (1 - h) + a * h - k * h * (1 - h)


def round_cone(p: np.ndarray, a: np.ndarray, b: np.ndarray, ra: float, rb: float,
               frame: np.ndarray, depth_ratio: float = DEPTH_RATIO) -> np.ndarray:
    """Distance (N,) to a round cone from `a` (radius ra) to `b` (radius rb), metres.

    `frame` (3, 3) has columns (axis, lateral, depth); the depth coordinate is stretched by
    1 / depth_ratio so the cross-section is an ellipse (an approximate distance).
    """
    q = (p - a) @ frame  # (N, 3) local (along, lateral, depth)
    q[:, 2] /= depth_ratio
    length = float(np.linalg.norm(b - a))
    x = np.hypot(q[:, 1], q[:, 2])
    y = q[:, 0]
    s = (ra - rb) / length
    c = np.sqrt(max(1.0 - s * s, 1e-12))
    k = -s * x + c * y  # position along the cone's tangent direction
    d_side = x * c + y * s - ra
    d_a = np.hypot(x, y) - ra
    d_b = np.hypot(x, y - length) - rb
    return np.where(k < 0.0, d_a, np.where(k > c * length, d_b, d_side))


def ellipsoid(p: np.ndarray, centre: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Approximate distance (N,) to an axis-aligned ellipsoid (Quilez's bound), metres."""
    q = (p - centre) / radii
    k0 = np.linalg.norm(q, axis=1)
    k1 = np.linalg.norm(q / radii, axis=1)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)


def polygon_distance_2d(pts: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Signed distance (N,) from 2D points (N, 2) to a closed simple polygon (M, 2); negative inside."""
    d2 = np.full(pts.shape[0], np.inf)
    inside = np.zeros(pts.shape[0], dtype=bool)
    m = poly.shape[0]
    for i in range(m):
        a, b = poly[i], poly[(i + 1) % m]
        e = b - a
        w = pts - a
        t = np.clip((w @ e) / (e @ e), 0.0, 1.0)
        d2 = np.minimum(d2, np.sum((w - t[:, None] * e) ** 2, axis=1))
        cond = (pts[:, 1] >= a[1]) != (pts[:, 1] >= b[1])
        with np.errstate(divide="ignore", invalid="ignore"):
            xcross = a[0] + (pts[:, 1] - a[1]) * e[0] / e[1]
        inside ^= cond & (pts[:, 0] < xcross)
    return np.where(inside, -1.0, 1.0) * np.sqrt(d2)


def palm_outline(skel: Skeleton) -> np.ndarray:
    """(M, 2) outline (x, z) of the palm sheet, counter-clockwise, from the knuckle and CMC positions."""
    j = skel.joints
    s = skel.scales[0]  # root scale (x, y, z)
    size = skel.proportions.hand_length_m / 0.19
    idx, mid, ring, pinky = j[1], j[4], j[10], j[7]
    back = 0.012  # the sheet ends this far proximal of the knuckles (metres at scale 1)
    sx, sz = s[0] * size, s[2] * size
    pts = [
        (-0.006 * sx, -0.015 * sz),
        (0.030 * sx, -0.031 * sz),
        (pinky[0] - 0.010 * sx, pinky[2] - 0.001 * sz),
        (pinky[0] - back * sx * 0.7, pinky[2] + 0.002 * sz),
        (ring[0] - back * sx, ring[2]),
        (mid[0] - back * sx, mid[2]),
        (idx[0] - back * sx, idx[2] - 0.001 * sz),
        (idx[0] - 0.016 * sx, idx[2] + 0.002 * sz),
        (0.040 * sx, 0.023 * sz),
        (-0.006 * sx, 0.013 * sz),
    ]
    return np.asarray(pts)


def hand_sdf(p: np.ndarray, skel: Skeleton) -> np.ndarray:
    """Approximate signed distance (N,) of points p (N, 3) to the rest-pose hand surface (metres)."""
    size = skel.proportions.hand_length_m / 0.19
    rs = skel.scales[0]  # root scale (x, y, z): palm length, thickness, breadth (size included)
    # Palm: a sheet in the plane y = yc, thickened by h(x).
    yc = 0.0035 * rs[1] * size
    d2 = polygon_distance_2d(p[:, [0, 2]], palm_outline(skel))
    x_rel = p[:, 0] / (0.08 * rs[0] * size)
    h = (0.0150 - 0.0025 * np.clip(x_rel, 0.0, 1.0)) * rs[1] * size
    dy = p[:, 1] - yc
    palm = np.hypot(np.maximum(d2, 0.0), dy) - h
    palm = np.where(d2 < 0.0, np.abs(dy) - h, palm)
    # Wrist stub: elliptic cylinder along x, closed by a rounded end at the proximal side.
    a_w, b_w = 0.0265 * rs[2] * size, 0.0185 * rs[1] * size
    ell = np.hypot(p[:, 2] / a_w, (p[:, 1] - yc) / b_w)
    d_rad = (ell - 1.0) * min(a_w, b_w)
    x0, x1, rho = -0.022 * rs[0] * size, 0.02 * rs[0] * size, 0.007 * size
    d_ax = np.maximum(x0 - p[:, 0], p[:, 0] - x1)
    q0, q1 = d_rad + rho, d_ax + rho
    stub = np.minimum(np.maximum(q0, q1), 0.0) + np.hypot(np.maximum(q0, 0.0), np.maximum(q1, 0.0)) - rho
    base = smin(palm, stub, 0.02 * size)
    # Thenar and hypothenar eminences (palm side).
    sc = rs * size
    thenar = ellipsoid(p, np.array([0.030, 0.010, 0.016]) * sc, np.array([0.028, 0.0125, 0.015]) * sc)
    hypo = ellipsoid(p, np.array([0.032, 0.008, -0.027]) * sc, np.array([0.030, 0.0105, 0.011]) * sc)
    base = smin(base, thenar, 0.012 * size)
    base = smin(base, hypo, 0.012 * size)
    # Thumb (blended into the palm) and fingers (blended with the palm, not with each other).
    thumb = _finger_sdf(p, skel, 0)
    d = smin(base, thumb, 0.014 * size)
    fingers = np.min(np.stack([_finger_sdf(p, skel, f) for f in range(1, 5)]), axis=0)
    return smin(d, fingers, 0.008 * size)


def _finger_sdf(p: np.ndarray, skel: Skeleton, f: int) -> np.ndarray:
    """Distance (N,) to finger f (FINGERS index): three round cones joined by a small smooth union."""

    chain = skel.chain(f)
    r = skel.radii[f]
    ids = FINGER_JOINTS[f]
    d = None
    for k in range(3):
        a, b = chain[k], chain[k + 1]
        rb = r[k + 1]
        if k == 2:  # the tip point is on the skin: end the cone one tip radius earlier
            u = (b - a) / np.linalg.norm(b - a)
            b = b - rb * u
        dk = round_cone(p, a, b, r[k], rb, skel.frames[ids[k]])
        d = dk if d is None else smin(d, dk, 0.004 * skel.proportions.hand_length_m / 0.19)
    return d
