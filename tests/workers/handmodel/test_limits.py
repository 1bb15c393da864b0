"""Tests of the anatomical joint frames, angle conversions and the joint-limit penalty."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from workers.handmodel.builtin import build_builtin_hand
from workers.handmodel.limits import (
    angles_to_pose,
    angles_to_pose_torch,
    joint_frames,
    joint_limit_penalty,
    pose_to_angles,
    within_limits,
)
from workers.handmodel.pose_sampler import canonical_poses


@pytest.fixture(scope="module")
def hand():
    return build_builtin_hand("right")


@pytest.fixture(scope="module")
def frames(hand):
    return joint_frames(hand)


def rotated(arrays, R: np.ndarray):
    """The same hand with its rest frame rotated by R (3, 3): a stand-in for MANO's different frame."""
    return replace(arrays, v_template=arrays.v_template @ R.T,
                   shapedirs=np.einsum("ij,vjs->vis", R, arrays.shapedirs))


def random_angles(frames, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(frames.lower_rad, frames.upper_rad, size=(n, 15, 3))


def test_frames_are_proper_rotations_matching_the_rest_frame(frames):
    B = frames.axes
    assert np.allclose(B @ B.transpose(0, 2, 1), np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(B), 1.0)
    assert np.allclose(frames.palm_normal, [0, 1, 0], atol=0.05)  # built-in: palm faces +y
    assert B[3, :, 0] @ [0, 0, 1] > 0.95  # middle MCP flexes about +z (radial axis)
    assert B[3, :, 2] @ [1, 0, 0] > 0.95  # and twists about the finger, +x


def test_angles_round_trip(frames):
    ang = random_angles(frames, 200, seed=1)
    back = pose_to_angles(angles_to_pose(ang, frames), frames)
    assert np.allclose(back, ang, atol=1e-7)


def test_flexion_moves_bones_toward_the_palm(hand, frames):
    J = hand.J_regressor @ hand.v_template
    ang = np.zeros((1, 15, 3))
    ang[0, 3, 0] = np.deg2rad(30.0)  # middle MCP flexion
    ang[0, 0, 1] = np.deg2rad(15.0)  # index MCP abduction (radial)
    rot = Rotation.from_rotvec(angles_to_pose(ang, frames).reshape(15, 3)).as_matrix()
    bone_mid = J[5] - J[4]
    bone_idx = J[2] - J[1]
    assert (rot[3] @ bone_mid)[1] > 0.4 * np.linalg.norm(bone_mid)  # toward the palm (+y)
    assert (rot[0] @ bone_idx)[2] > bone_idx[2] + 0.2 * np.linalg.norm(bone_idx)  # toward the thumb


def test_left_angles_give_mirrored_poses(hand, frames):
    left = joint_frames(build_builtin_hand("left"))
    ang = random_angles(frames, 20, seed=2)
    assert np.allclose(angles_to_pose(ang, left), angles_to_pose(ang, frames) * np.tile([1, -1, -1], 15),
                       atol=1e-9)


def test_frames_follow_any_rest_frame(hand, frames):
    R = Rotation.from_euler("xyz", [30, -70, 120], degrees=True).as_matrix()
    other = joint_frames(rotated(hand, R))
    assert np.allclose(other.axes, R @ frames.axes, atol=1e-9)
    ang = random_angles(frames, 10, seed=3)
    p0 = angles_to_pose(ang, frames).reshape(10, 15, 3)
    p1 = angles_to_pose(ang, other).reshape(10, 15, 3)
    assert np.allclose(p1, p0 @ R.T, atol=1e-9)


def test_canonical_poses_are_inside_the_limits(hand, frames):
    for name, pose in canonical_poses(hand).items():
        assert within_limits(pose_to_angles(pose, frames), frames, tol_rad=1e-6), name
        penalty = joint_limit_penalty(torch.as_tensor(pose)[None], frames)
        assert float(penalty[0]) == 0.0, name


def test_hyperextension_is_penalised_with_a_gradient_pointing_back(frames):
    ang = np.zeros((1, 15, 3))
    ang[0, 0, 0] = np.deg2rad(-80.0)  # index MCP hyperextended by 80 deg (limit 45)
    ang[0, 4, 0] = np.deg2rad(-40.0)  # middle PIP bent backwards
    pose = torch.tensor(angles_to_pose(ang, frames), requires_grad=True)
    penalty = joint_limit_penalty(pose, frames)
    assert penalty.shape == (1,) and float(penalty.detach()[0]) > 0.1
    penalty.sum().backward()
    stepped = (pose - 0.05 * pose.grad).detach()
    assert float(joint_limit_penalty(stepped, frames)[0]) < float(penalty.detach()[0])
    new_ang = pose_to_angles(stepped.numpy(), frames)
    assert new_ang[0, 0, 0] > ang[0, 0, 0] and new_ang[0, 4, 0] > ang[0, 4, 0]  # flexes back


def test_penalty_is_quadratic_outside_and_zero_inside(frames):
    def pen(deg: float) -> float:
        ang = torch.zeros(1, 15, 3, dtype=torch.float64)
        ang[0, 1, 0] = np.deg2rad(deg)  # index PIP, limit 110 deg
        return float(joint_limit_penalty(angles_to_pose_torch(ang, frames), frames)[0])

    assert pen(60.0) == 0.0 and pen(109.0) == 0.0
    assert pen(130.0) == pytest.approx(4 * pen(120.0), rel=1e-3)


def test_bad_shapes_raise(frames):
    with pytest.raises(ValueError, match="45"):
        joint_limit_penalty(torch.zeros(2, 44, dtype=torch.float64), frames)
