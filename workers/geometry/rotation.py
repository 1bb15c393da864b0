"""Axis-angle rotations (Rodrigues' formula), once for numpy and torch (see `workers.geometry.arrays`).

Frames: a rotation vector r (radians) rotates by |r| about r / |r|, right-handed; the matrix acts on column
vectors (x' = R x). OpenCV's `cv2.Rodrigues` and scipy's `Rotation.from_rotvec` give the same matrices.
"""

from __future__ import annotations

from workers.geometry.arrays import Array, eye_like, namespace


def skew(v: Array) -> Array:
    """Cross-product matrices: v (..., 3) -> (..., 3, 3) with skew(v) @ w = v x w."""
    xp = namespace(v)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    zero = xp.zeros_like(x)
    return xp.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(*v.shape[:-1], 3, 3)


def axis_angle_to_matrix(rot_vecs: Array) -> Array:
    """Rodrigues' formula: axis-angle (..., 3) radians -> rotation matrices (..., 3, 3), same kind and dtype.

    R = I + a(t) K + b(t) K^2 with K = skew(r), a = sin t / t, b = (1 - cos t) / t^2, t = |r|; both
    coefficients switch to their Taylor series near t = 0 so values and gradients stay finite there.
    """
    xp = namespace(rot_vecs)
    angle2 = (rot_vecs * rot_vecs).sum(-1, keepdims=True)[..., None]  # (..., 1, 1)
    small = angle2 < 1e-6
    safe2 = xp.where(small, xp.ones_like(angle2), angle2)
    safe = xp.sqrt(safe2)
    a = xp.where(small, 1 - angle2 / 6 + angle2 * angle2 / 120, xp.sin(safe) / safe)
    b = xp.where(small, 0.5 - angle2 / 24 + angle2 * angle2 / 720, (1 - xp.cos(safe)) / safe2)
    K = skew(rot_vecs)
    return eye_like(3, K) + a * K + b * (K @ K)
