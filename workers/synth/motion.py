"""Continuous hand motion: smooth trajectories between sampled key poses.

Between keys, every joint rotation (articulation and global orientation) is slerped with a smoothstep
ease (velocity zero at the keys, C1 in time), and the wrist position and the forearm's exit point are
eased the same way. Keys are placed every `key_interval` frames.

World frame (docs/conventions.md): origin at the rig's centre, z up, metres; the forearm enters through
the -y face, so the hand points roughly along +y.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from workers.handmodel.keypoints import NUM_POSE

# The forearm leaves the rig through the -y face; its far end is placed at this y (outside the cube).
EXIT_Y_M = -0.75
MAX_FOREARM_TILT_RAD = np.deg2rad(8.0)


@dataclass(frozen=True)
class HandFrameAxes:
    """Unit axes of a hand: forward (wrist -> middle knuckle), palm (out of the palm), lateral."""

    forward: np.ndarray
    palm: np.ndarray

    @property
    def lateral(self) -> np.ndarray:
        return np.cross(self.forward, self.palm)

    def matrix(self) -> np.ndarray:
        """(3, 3) columns forward, palm, lateral."""
        return np.stack([self.forward, self.palm, self.lateral], axis=1)


def hand_axes(keypoints: np.ndarray, side: str = "right") -> HandFrameAxes:
    """The hand frame from FreiHAND keypoints (21, 3): forward to the middle knuckle, palm normal
    from the index and pinky knuckles (sign by hand side), made orthonormal."""
    wrist = keypoints[0]
    forward = keypoints[9] - wrist
    forward /= np.linalg.norm(forward)
    palm = np.cross(keypoints[5] - wrist, keypoints[17] - wrist)
    if side == "left":
        palm = -palm
    palm -= (palm @ forward) * forward
    palm /= np.linalg.norm(palm)
    return HandFrameAxes(forward=forward, palm=palm)


@dataclass(frozen=True)
class MotionPlan:
    """Key states of one sequence; `evaluate` interpolates them.

    Attributes:
        key_frames: (K,) int frame index of each key, increasing, first 0, last >= the last frame.
        key_pose: (K, 45) articulation, axis-angle radians.
        key_orient: (K, 3) global orientation (model -> world) as a rotation vector, radians.
        key_wrist_m: (K, 3) wrist keypoint position, world frame, metres.
        key_exit_m: (K, 3) where the forearm's axis leaves the rig, world frame, metres.
    """

    key_frames: np.ndarray
    key_pose: np.ndarray
    key_orient: np.ndarray
    key_wrist_m: np.ndarray
    key_exit_m: np.ndarray


@dataclass(frozen=True)
class MotionSample:
    """The interpolated state at T frames.

    Attributes:
        pose: (T, 45) articulation, axis-angle radians.
        global_orient: (T, 3) rotation vector, radians.
        wrist_m: (T, 3) wrist keypoint target, world frame, metres.
        forearm_axis: (T, 3) unit direction from the wrist towards the elbow.
    """

    pose: np.ndarray
    global_orient: np.ndarray
    wrist_m: np.ndarray
    forearm_axis: np.ndarray


def _smoothstep(t: np.ndarray) -> np.ndarray:
    return t * t * (3.0 - 2.0 * t)


def slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (..., 4) with weights t (...,), shortest arc."""
    dot = np.sum(q0 * q1, axis=-1)
    q1 = np.where(dot[..., None] < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(theta)
    small = sin < 1e-6
    w0 = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / np.where(small, 1.0, sin))
    w1 = np.where(small, t, np.sin(t * theta) / np.where(small, 1.0, sin))
    q = w0[..., None] * q0 + w1[..., None] * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def key_orientation(forearm_axis: np.ndarray, roll_rad: float, flexion_rad: float, deviation_rad: float,
                    rest_axes: HandFrameAxes) -> np.ndarray:
    """Global orientation (3,) rotation vector that points the hand away from the forearm.

    Args:
        forearm_axis: (3,) unit, wrist -> elbow.
        roll_rad: pronation / supination about the forearm axis (0 = palm facing world +z... roughly).
        flexion_rad: wrist flexion, bending the hand towards its palm.
        deviation_rad: radial / ulnar deviation, about the palm normal.
        rest_axes: the hand's axes at zero orientation.
    """
    forward = -forearm_axis / np.linalg.norm(forearm_axis)
    up = np.array([0.0, 0.0, 1.0]) - forward[2] * forward
    if np.linalg.norm(up) < 1e-6:
        up = np.array([1.0, 0.0, 0.0]) - forward[0] * forward
    up /= np.linalg.norm(up)
    palm = Rotation.from_rotvec(forward * roll_rad).apply(up)
    target = HandFrameAxes(forward=forward, palm=palm)
    bend = Rotation.from_rotvec(target.lateral * -flexion_rad) * Rotation.from_rotvec(palm * deviation_rad)
    R = bend.as_matrix() @ target.matrix() @ rest_axes.matrix().T
    return Rotation.from_matrix(R).as_rotvec()


def plan_motion(rng: np.random.Generator, num_frames: int, key_poses: np.ndarray, rest_axes: HandFrameAxes,
                *, key_interval: tuple[int, int] = (6, 12), wrist_sd_m: float = 0.035) -> MotionPlan:
    """Key states for a sequence of `num_frames` frames.

    Args:
        rng: the sequence's random generator.
        num_frames: frames in the sequence.
        key_poses: (K', 45) articulations to visit in order (K' >= number of keys needed; reused cyclically).
        rest_axes: the hand model's axes at zero global orientation (from its rest keypoints).
        key_interval: (min, max) frames between keys.
        wrist_sd_m: standard deviation of the wrist position around the rig centre, metres.
    """
    frames = [0]
    while frames[-1] < num_frames - 1:
        frames.append(frames[-1] + int(rng.integers(key_interval[0], key_interval[1] + 1)))
    if len(frames) == 1:
        frames.append(1)
    K = len(frames)
    key_poses = np.asarray(key_poses, dtype=np.float64)
    if key_poses.ndim != 2 or key_poses.shape[1] != NUM_POSE or len(key_poses) == 0:
        raise ValueError(f"key_poses must have shape (K, {NUM_POSE}), got {key_poses.shape}")
    pose = key_poses[np.arange(K) % len(key_poses)]
    wrist = np.clip(rng.normal(0.0, wrist_sd_m, (K, 3)), -2 * wrist_sd_m, 2 * wrist_sd_m)
    wrist[:, 1] -= 0.04  # the knuckles, not the wrist, sit near the centre
    # The forearm stays within MAX_FOREARM_TILT_RAD of -y: its vanishing point then lies outside every
    # camera's field of view (the +y cameras look towards -y at 54.7 deg from it), so the arm always
    # leaves the picture. The set of allowed directions is convex, so interpolated frames obey it too.
    radius = np.sqrt(rng.uniform(0, 1, K)) * np.tan(MAX_FOREARM_TILT_RAD) * (wrist[:, 1] - EXIT_Y_M)
    angle = rng.uniform(0, 2 * np.pi, K)
    exits = np.stack([wrist[:, 0] + radius * np.cos(angle), np.full(K, EXIT_Y_M),
                      wrist[:, 2] + radius * np.sin(angle)], axis=1)
    roll0 = rng.uniform(-np.pi, np.pi)
    rolls = roll0 + np.cumsum(np.concatenate([[0.0], rng.uniform(-1.6, 1.6, K - 1)]))
    orients = []
    for k in range(K):
        axis = exits[k] - wrist[k]
        orients.append(key_orientation(axis / np.linalg.norm(axis), rolls[k], rng.uniform(-0.7, 0.6),
                                       rng.uniform(-0.3, 0.3), rest_axes))
    return MotionPlan(key_frames=np.asarray(frames), key_pose=pose, key_orient=np.asarray(orients),
                      key_wrist_m=wrist, key_exit_m=exits)


def evaluate(plan: MotionPlan, frames: np.ndarray) -> MotionSample:
    """Interpolate the plan at frame indices `frames` (T,) (fractional allowed)."""
    f = np.asarray(frames, dtype=np.float64)
    seg = np.clip(np.searchsorted(plan.key_frames, f, side="right") - 1, 0, len(plan.key_frames) - 2)
    f0, f1 = plan.key_frames[seg], plan.key_frames[seg + 1]
    t = _smoothstep(np.clip((f - f0) / (f1 - f0), 0.0, 1.0))  # (T,)

    def rotvec_slerp(keys: np.ndarray) -> np.ndarray:  # keys (K, J, 3) -> (T, J, 3)
        K, J = keys.shape[:2]
        quats = Rotation.from_rotvec(keys.reshape(-1, 3)).as_quat().reshape(K, J, 4)
        q = slerp(quats[seg], quats[seg + 1], np.repeat(t[:, None], J, axis=1))
        return Rotation.from_quat(q.reshape(-1, 4)).as_rotvec().reshape(len(f), J, 3)

    pose = rotvec_slerp(plan.key_pose.reshape(len(plan.key_frames), 15, 3)).reshape(len(f), NUM_POSE)
    orient = rotvec_slerp(plan.key_orient[:, None])[:, 0]
    lerp = lambda keys: keys[seg] + t[:, None] * (keys[seg + 1] - keys[seg])  # noqa: E731
    wrist = lerp(plan.key_wrist_m)
    axis = lerp(plan.key_exit_m) - wrist
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return MotionSample(pose=pose, global_orient=orient, wrist_m=wrist, forearm_axis=axis)
