"""Tests of the seeded pose sampler (canonical poses, couplings, limits, pose bank)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from smplx.lbs import lbs

from workers.handmodel.builtin import build_builtin_hand
from workers.handmodel.limits import joint_frames, pose_to_angles, within_limits
from workers.handmodel.pose_sampler import (
    CANONICAL_NAMES,
    PoseSampler,
    apply_couplings,
    canonical_poses,
    pose_bank,
    sample,
)

MCP_ROWS = (0, 3, 9, 6)  # index, middle, ring, pinky MCP rows (MANO joint id - 1)
PIP_DIP_ROWS = ((1, 2), (4, 5), (10, 11), (7, 8))


@pytest.fixture(scope="module")
def hand():
    return build_builtin_hand("right")


@pytest.fixture(scope="module")
def frames(hand):
    return joint_frames(hand)


def test_canonical_poses_cover_the_gestures(hand):
    poses = canonical_poses(hand)
    for name in ("flat", "fist", "count_1", "count_2", "count_3", "count_4", "count_5", "pinch",
                 "cylinder_grasp", "sphere_grasp", "disc_grasp", "asl_a", "asl_l", "asl_y"):
        assert name in poses and poses[name].shape == (45,)
    assert np.all(poses["flat"] == 0.0)
    assert set(poses) == set(CANONICAL_NAMES)


def test_sampling_is_deterministic_per_seed(hand):
    a = sample(64, np.random.default_rng(7), hand)
    b = sample(64, np.random.default_rng(7), hand)
    c = sample(64, np.random.default_rng(8), hand)
    assert a.shape == (64, 45) and a.tobytes() == b.tobytes()
    assert not np.allclose(a, c)
    assert pose_bank(50, seed=1, arrays=hand).tobytes() == pose_bank(50, seed=1, arrays=hand).tobytes()


def test_samples_respect_limits_and_couplings(hand, frames):
    ang = pose_to_angles(sample(400, np.random.default_rng(0), hand), frames)
    assert within_limits(ang, frames, tol_rad=1e-5).all()
    for pip, dip in PIP_DIP_ROWS:
        assert np.all(np.abs(ang[:, dip, 0] - 2 / 3 * ang[:, pip, 0]) < np.deg2rad(8.0))
    grasps = PoseSampler(frames, names=("flat", "relaxed", "fist", "cylinder_grasp", "sphere_grasp", "pinch"))
    ang = grasps.sample_angles(400, np.random.default_rng(1))
    mcp = ang[:, MCP_ROWS, 0]
    assert np.abs(np.diff(mcp, axis=1)).max() <= np.deg2rad(30.0) + 1e-9
    assert ang.std(axis=0)[MCP_ROWS, 0].min() > np.deg2rad(5.0)  # it does vary


def test_couplings_keep_intentional_gestures(frames):
    base = np.zeros((1, 15, 3))
    base[0, 3, 0] = base[0, 9, 0] = base[0, 6, 0] = np.deg2rad(85.0)  # count_1: index out, rest folded
    out = apply_couplings(base.copy(), base, frames)
    assert np.allclose(out[0, MCP_ROWS, 0], base[0, MCP_ROWS, 0], atol=1e-3)
    flat = np.zeros((1, 15, 3))
    wild = flat.copy()
    wild[0, 0, 0] = np.deg2rad(80.0)
    out = apply_couplings(wild, flat, frames)
    assert abs(out[0, 0, 0] - out[0, 3, 0]) <= np.deg2rad(30.0) + 1e-9


def test_pose_bank_starts_with_the_canonical_poses(hand):
    bank = pose_bank(100, seed=0, arrays=hand)
    canon = np.stack(list(canonical_poses(hand).values()))
    assert bank.shape == (100, 45)
    assert np.array_equal(bank[: len(canon)], canon)


def test_works_for_a_left_hand(hand):
    left = build_builtin_hand("left")
    fl = joint_frames(left)
    ang = pose_to_angles(sample(100, np.random.default_rng(0), left), fl)
    assert within_limits(ang, fl, tol_rad=1e-5).all()
    ref = pose_to_angles(sample(100, np.random.default_rng(0), hand), joint_frames(hand))
    assert np.allclose(ang, ref, atol=1e-7)


def _tips_to_palm(arrays, pose: np.ndarray) -> np.ndarray:
    t = lambda x: torch.as_tensor(np.asarray(x), dtype=torch.float64)  # noqa: E731
    full = torch.cat([torch.zeros(1, 3, dtype=torch.float64), t(pose)[None]], 1)
    v, J = lbs(torch.zeros(1, 10, dtype=torch.float64), full, t(arrays.v_template), t(arrays.shapedirs),
               t(arrays.posedirs.reshape(arrays.num_vertices * 3, -1).T), t(arrays.J_regressor),
               torch.as_tensor(arrays.parents), t(arrays.weights))
    v, J = v[0].numpy(), J[0].numpy()
    palm_centre = (J[0] + J[4]) / 2 + np.array([0.0, 0.015, 0.0])  # on the palm side
    return np.linalg.norm(v[arrays.fingertip_vertex_ids[1:]] - palm_centre, axis=1)


def test_fist_brings_fingertips_to_the_palm(hand):
    poses = canonical_poses(hand)
    flat, fist = _tips_to_palm(hand, poses["flat"]), _tips_to_palm(hand, poses["fist"])
    assert np.all(fist < 0.6 * flat)
    assert np.all(fist < 0.07)
