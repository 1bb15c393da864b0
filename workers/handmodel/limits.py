"""Anatomical joint frames and limits for any MANO-compatible hand model.

Each of the 15 articulated joints (MANO order, joints 1..15) gets an anatomical frame derived from the
rest pose alone (regressed joint centres, fingertip vertices, side), so it works for the built-in hand
and for the real MANO files, whose rest frames differ:

- twist axis   t = s * (bone direction), the bone running from the joint to its child (or fingertip);
  s = +1 for a right hand, -1 for a left hand (mirror symmetry: equal angles give mirrored poses).
- flexion axis f = unit(bone x target): positive flexion turns the bone toward the `target` direction:
  the palm normal for fingers; for the thumb CMC the ulnar side (across the palm); for the thumb MCP
  and IP the thumb pad (the palm normal turned by `THUMB_PAD_ANGLE_DEG` toward the ulnar side).
- abduction axis a = t x f: positive abduction turns the bone toward the radial side (toward the
  thumb) for fingers; for the thumb, toward the palm (palmar abduction).
- twist: right-hand rotation about t. For the thumb, negative twist is pronation (the pad turns
  toward the fingers, as in opposition and in a fist); for a right index, positive twist turns the
  finger pad toward the thumb.

Angles (flex, abduct, twist) in radians map to a local rotation R = Rf(flex) Ra(abduct) Rt(twist)
(twist applied first), i.e. R = B Rx(flex) Ry(abduct) Rz(twist) B^T with B = [f, a, t]; the
axis-angle of R, expressed in the rest frame, is the joint's MANO pose entry. The middle angle
(abduction) is the singular one (at +-90 deg), which anatomical poses never reach.

Palm normal n: for a right hand n = unit(r x d) with d = middle MCP - wrist and r = index MCP - pinky
MCP (radial direction); for a left hand n = -unit(r x d).

Limits come from /work/shared/HAND_ANATOMY.md (clinical ranges of motion), slightly generous.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from workers.geometry.rotation import axis_angle_to_matrix
from workers.handmodel.arrays import HandModelArrays
from workers.handmodel.keypoints import NUM_JOINTS

NUM_ARTICULATED = NUM_JOINTS - 1
THUMB_PAD_ANGLE_DEG = 60.0
# MANO joint ids per finger (base, middle, last), thumb first; and fingertip order (thumb..pinky).
_FINGER_JOINTS = ((13, 14, 15), (1, 2, 3), (4, 5, 6), (10, 11, 12), (7, 8, 9))
_THUMB = (13, 14, 15)

# Limits in degrees as (flex lo, hi), (abduct lo, hi), (twist lo, hi); abduction positive = radial.
_FINGER_MCP = {
    "index": ((-45.0, 95.0), (-20.0, 25.0), (-15.0, 15.0)),
    "middle": ((-45.0, 95.0), (-20.0, 20.0), (-15.0, 15.0)),
    "ring": ((-45.0, 95.0), (-22.0, 18.0), (-15.0, 15.0)),
    "pinky": ((-45.0, 95.0), (-32.0, 18.0), (-15.0, 15.0)),
}
_PIP = ((-5.0, 110.0), (-8.0, 8.0), (-10.0, 10.0))
_DIP = ((-10.0, 90.0), (-8.0, 8.0), (-10.0, 10.0))
_THUMB_LIMITS = (
    ((-25.0, 60.0), (-20.0, 50.0), (-45.0, 20.0)),  # CMC: flex across the palm, palmar abduction, twist
    ((-10.0, 60.0), (-12.0, 12.0), (-15.0, 15.0)),  # MCP
    ((-15.0, 85.0), (-8.0, 8.0), (-10.0, 10.0)),  # IP
)


def default_limits_deg() -> np.ndarray:
    """(15, 3, 2) lower/upper limits in degrees for joints 1..15 (MANO order), (flex, abduct, twist)."""
    lim = np.zeros((NUM_ARTICULATED, 3, 2))
    for name, ids in zip(("index", "middle", "ring", "pinky"), (_FINGER_JOINTS[1], _FINGER_JOINTS[2],
                                                                _FINGER_JOINTS[3], _FINGER_JOINTS[4]),
                         strict=True):
        lim[ids[0] - 1] = _FINGER_MCP[name]
        lim[ids[1] - 1] = _PIP
        lim[ids[2] - 1] = _DIP
    for k, j in enumerate(_THUMB):
        lim[j - 1] = _THUMB_LIMITS[k]
    return lim


@dataclass(frozen=True)
class JointFrames:
    """Anatomical frames and limits of the 15 articulated joints (index = MANO joint id - 1).

    Attributes:
        axes: (15, 3, 3) float64 rotation matrices B with columns (flex axis, abduction axis, twist
            axis), unit vectors in the model's rest frame.
        lower_rad, upper_rad: (15, 3) limits of (flex, abduct, twist) in radians.
        palm_normal: (3,) unit palm normal in the rest frame.
        side: "right" or "left".
    """

    axes: np.ndarray
    lower_rad: np.ndarray
    upper_rad: np.ndarray
    palm_normal: np.ndarray
    side: str

    def torch_axes(self, like: torch.Tensor) -> torch.Tensor:
        return self._tensor("axes", like)

    def torch_limits(self, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self._tensor("lower_rad", like), self._tensor("upper_rad", like)

    def _tensor(self, name: str, like: torch.Tensor) -> torch.Tensor:
        # Cached per dtype and device: the fitting loop asks every iteration.
        cache = self.__dict__.setdefault("_torch_cache", {})
        key = (name, like.dtype, like.device)
        if key not in cache:
            cache[key] = torch.as_tensor(getattr(self, name), dtype=like.dtype, device=like.device)
        return cache[key]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def rest_joints(arrays: HandModelArrays) -> np.ndarray:
    """(16, 3) rest joint centres J_regressor @ v_template (metres, rest frame)."""
    return arrays.J_regressor @ arrays.v_template


def joint_frames(arrays: HandModelArrays, limits_deg: np.ndarray | None = None) -> JointFrames:
    """Anatomical frames of `arrays`' rest pose (any MANO-compatible model, right or left)."""
    J = rest_joints(arrays)
    tips = arrays.v_template[arrays.fingertip_vertex_ids]  # thumb, index, middle, ring, pinky
    s = 1.0 if arrays.side == "right" else -1.0
    d = _unit(J[4] - J[0])
    radial = J[1] - J[7]
    radial = _unit(radial - (radial @ d) * d)
    n = s * _unit(np.cross(radial, d))
    ulnar = -radial
    axes = np.zeros((NUM_ARTICULATED, 3, 3))
    for f, ids in enumerate(_FINGER_JOINTS):
        for k, j in enumerate(ids):
            end = J[ids[k + 1]] if k < 2 else tips[f]
            bone = _unit(end - J[j])
            if f != 0:
                target = n
            elif k == 0:
                target = ulnar
            else:
                pad_angle = np.deg2rad(THUMB_PAD_ANGLE_DEG)
                target = np.cos(pad_angle) * n + np.sin(pad_angle) * ulnar
            target = target - (target @ bone) * bone
            flex = _unit(np.cross(bone, target))
            twist = s * bone
            abd = np.cross(twist, flex)
            # Rotating the bone about `abd` moves it toward `flex` x ... ; make positive abduction go
            # radial (fingers) or palmar (thumb), mirror-consistently.
            want = n if f == 0 else radial
            moved = np.cross(abd, bone)
            if moved @ want < 0:  # can only happen for an unusual rest geometry; keep B proper
                abd, twist = -abd, -twist
            axes[j - 1] = np.stack([flex, abd, twist], axis=1)
    lim = np.deg2rad(default_limits_deg() if limits_deg is None else limits_deg)
    return JointFrames(axes=axes, lower_rad=lim[..., 0], upper_rad=lim[..., 1], palm_normal=n,
                       side=arrays.side)


# ---------------------------------------------------------------------------------------------------
# Rotations (torch, differentiable)


def _matrix_to_axis_angle(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 3) axis-angle (radians) for rotations below pi; finite gradients at 0."""
    v = 0.5 * torch.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                           R[..., 1, 0] - R[..., 0, 1]], -1)  # sin(angle) * axis
    c = 0.5 * (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1.0)  # cos(angle)
    s2 = (v * v).sum(-1, keepdim=True)
    small = s2 < 1e-12
    s = torch.where(small, torch.ones_like(s2), s2).sqrt()
    scale = torch.where(small, 1.0 + s2 / 6.0, torch.atan2(s, c[..., None]) / s)
    return v * scale


def _euler_matrix(angles: torch.Tensor) -> torch.Tensor:
    """Local R = Rx(flex) Ry(abduct) Rz(twist): angles (..., 3) -> (..., 3, 3)."""
    a, b, c = angles.unbind(-1)
    ca, sa, cb, sb, cc, sc = a.cos(), a.sin(), b.cos(), b.sin(), c.cos(), c.sin()
    row0 = torch.stack([cb * cc, -cb * sc, sb], -1)
    row1 = torch.stack([sa * sb * cc + ca * sc, -sa * sb * sc + ca * cc, -sa * cb], -1)
    row2 = torch.stack([-ca * sb * cc + sa * sc, ca * sb * sc + sa * cc, ca * cb], -1)
    return torch.stack([row0, row1, row2], -2)


def angles_to_pose_torch(angles: torch.Tensor, frames: JointFrames) -> torch.Tensor:
    """Anatomical angles (B, 15, 3) radians (flex, abduct, twist) -> MANO pose (B, 45) axis-angle."""
    if angles.shape[-2:] != (NUM_ARTICULATED, 3):
        raise ValueError(f"angles must have shape (B, 15, 3), got {tuple(angles.shape)}")
    B = frames.torch_axes(angles)  # (15, 3, 3)
    R = B @ _euler_matrix(angles) @ B.transpose(-1, -2)
    return _matrix_to_axis_angle(R).reshape(*angles.shape[:-2], NUM_ARTICULATED * 3)


def pose_to_angles_torch(pose: torch.Tensor, frames: JointFrames) -> torch.Tensor:
    """MANO pose (B, 45) axis-angle radians -> anatomical angles (B, 15, 3) (flex, abduct, twist)."""
    if pose.shape[-1] != NUM_ARTICULATED * 3:
        raise ValueError(f"pose must have shape (B, 45), got {tuple(pose.shape)}")
    B = frames.torch_axes(pose)
    R = axis_angle_to_matrix(pose.reshape(*pose.shape[:-1], NUM_ARTICULATED, 3))
    L = B.transpose(-1, -2) @ R @ B  # local rotation in (flex, abduct, twist) coordinates
    abd = torch.asin(L[..., 0, 2].clamp(-1 + 1e-7, 1 - 1e-7))
    flex = torch.atan2(-L[..., 1, 2], L[..., 2, 2])
    twist = torch.atan2(-L[..., 0, 1], L[..., 0, 0])
    return torch.stack([flex, abd, twist], -1)


def angles_to_pose(angles: np.ndarray, frames: JointFrames) -> np.ndarray:
    """NumPy wrapper of `angles_to_pose_torch`: (..., 15, 3) radians -> (..., 45) axis-angle."""
    a = np.asarray(angles, dtype=np.float64)
    flat = torch.from_numpy(a.reshape(-1, NUM_ARTICULATED, 3))
    return angles_to_pose_torch(flat, frames).numpy().reshape(*a.shape[:-2], NUM_ARTICULATED * 3)


def pose_to_angles(pose: np.ndarray, frames: JointFrames) -> np.ndarray:
    """NumPy wrapper of `pose_to_angles_torch`: (..., 45) axis-angle -> (..., 15, 3) radians."""
    p = np.asarray(pose, dtype=np.float64)
    flat = torch.from_numpy(p.reshape(-1, NUM_ARTICULATED * 3))
    return pose_to_angles_torch(flat, frames).numpy().reshape(*p.shape[:-1], NUM_ARTICULATED, 3)


def joint_limit_penalty(pose: torch.Tensor, frames: JointFrames) -> torch.Tensor:
    """Quadratic penalty (B,) in rad^2: sum over joints and angles of the squared excess beyond the limits.

    pose: (B, 45) full articulation in axis-angle (radians, rest frame; after adding hands_mean when
    PCA is used). Zero inside the limits; differentiable.
    """
    ang = pose_to_angles_torch(pose, frames)
    lo, hi = frames.torch_limits(pose)
    excess = torch.relu(lo - ang) + torch.relu(ang - hi)
    return (excess * excess).sum(dim=(-1, -2))


def within_limits(angles: np.ndarray, frames: JointFrames, tol_rad: float = 1e-6) -> np.ndarray:
    """(...,) bool: all 15 x 3 angles (..., 15, 3) inside [lower - tol, upper + tol]."""
    ok = (angles >= frames.lower_rad - tol_rad) & (angles <= frames.upper_rad + tol_rad)
    return ok.all(axis=(-1, -2))


__all__ = [
    "JointFrames",
    "angles_to_pose",
    "angles_to_pose_torch",
    "default_limits_deg",
    "joint_frames",
    "joint_limit_penalty",
    "pose_to_angles",
    "pose_to_angles_torch",
    "rest_joints",
    "within_limits",
]
