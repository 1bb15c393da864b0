"""Learned keypoint offsets (workers/detector/keypoint_offsets.py): a convention difference expressed in each
bone's frame is recovered from labelled frames of hands in every orientation and flexion, despite gross outliers;
keypoints without a frame stay where they are; too few frames learn nothing; bad input is refused. The pose term:
an error that follows the hand's pose is learned in the palm's frame, whatever the hand's place and orientation."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from workers.detector.keypoint_offsets import (
    MIN_FRAMES,
    PARENT,
    POSE_LEVERAGE_SCALE,
    POSE_MIN_FRAMES,
    KeypointOffsets,
    bone_frames,
    fit_keypoint_offsets,
    fit_pose_correction,
    palm_frame,
)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def hands(n: int, rng: np.random.Generator) -> np.ndarray:
    """n skeletons (n, 21, 3) metres: a palm fan of MCPs, fingers flexed by random angles towards the palm's normal,
    randomly oriented and placed."""
    out = np.zeros((n, 21, 3))
    for i in range(n):
        points = np.zeros((21, 3))
        for f, spread in enumerate(np.deg2rad([-50, -20, 0, 18, 36])):
            base = 4 * f + 1
            direction = np.array([np.sin(spread), np.cos(spread), 0.0])
            points[base] = 0.09 * direction if f else 0.03 * direction
            flex = 0.0
            for j, length in enumerate((0.045, 0.028, 0.022)):
                flex += rng.uniform(0, np.deg2rad(60))
                bend = np.cos(flex) * direction + np.sin(flex) * np.array([0.0, 0.0, -1.0])
                points[base + j + 1] = points[base + j] + length * bend
        out[i] = points @ random_rotation(rng).T + rng.normal(0, 0.3, 3)
    return out


def test_bone_frames_are_rotations_along_each_bone():
    points = hands(3, np.random.default_rng(0))
    frames = bone_frames(points)
    assert frames.shape == (3, 21, 3, 3)
    np.testing.assert_allclose(frames @ np.swapaxes(frames, -1, -2), np.broadcast_to(np.eye(3), frames.shape),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(frames), 1.0, atol=1e-12)
    bone = points - points[:, PARENT]
    np.testing.assert_allclose(frames[..., 0], bone / np.linalg.norm(bone, axis=-1, keepdims=True), atol=1e-12)


def test_offsets_in_the_bone_frame_are_recovered_despite_outliers():
    rng = np.random.default_rng(1)
    truth = rng.normal(0, 0.006, (21, 3))  # up to ~1-2 cm, as the detector's fingertips
    lifted = hands(40, rng)
    labels = lifted + np.einsum("nkij,kj->nki", bone_frames(lifted), truth) + rng.normal(0, 0.001, lifted.shape)
    gross = rng.random((40, 21)) < 0.1  # a detector's gross failures: 3-6 cm off
    labels[gross] += rng.choice([-1, 1], (gross.sum(), 3)) * rng.uniform(0.03, 0.06, (gross.sum(), 3))
    learned = fit_keypoint_offsets(lifted, labels)
    np.testing.assert_allclose(learned.offsets_m, truth, atol=0.0012)
    assert np.all(learned.frames_used == 40)
    summary = learned.summary()
    np.testing.assert_allclose(summary["along_bone_mm"], 1000 * truth[:, 0], atol=1.2)
    assert summary["samples"] == [40] * 21
    # On other hands the correction removes the convention difference.
    held = hands(10, rng)
    target = held + np.einsum("nkij,kj->nki", bone_frames(held), truth)
    before = np.linalg.norm(held - target, axis=-1).mean()
    after = np.linalg.norm(learned.apply(held) - target, axis=-1).mean()
    assert after < 0.15 * before, (before, after)


def test_keypoints_without_a_frame_stay_and_few_frames_learn_nothing():
    rng = np.random.default_rng(2)
    lifted = hands(12, rng)
    labels = lifted + 0.01
    lifted[: 12 - (MIN_FRAMES - 1), 8] = np.nan  # index tip lifted in MIN_FRAMES - 1 frames: not learned
    lifted[: 12 - MIN_FRAMES, 4] = np.nan  # thumb tip lifted in MIN_FRAMES frames: learned
    learned = fit_keypoint_offsets(lifted, labels)
    assert learned.frames_used[8] == 0 and np.all(learned.offsets_m[8] == 0)
    assert learned.frames_used[4] == MIN_FRAMES and np.any(learned.offsets_m[4] != 0)
    assert learned.frames_used[7] == 12 and np.any(learned.offsets_m[7] != 0)
    one = hands(1, rng)[0]
    one[17] = np.nan  # the pinky's MCP: no palm normal, so no keypoint has a frame
    np.testing.assert_array_equal(learned.apply(one), one)
    assert np.all(KeypointOffsets.none().apply(one)[np.isfinite(one)] == one[np.isfinite(one)])


def test_bad_input_is_refused():
    lifted = hands(10, np.random.default_rng(3))
    with pytest.raises(ValueError, match="must both be"):
        fit_keypoint_offsets(lifted[:, :20], lifted[:, :20])
    with pytest.raises(ValueError, match="must both be"):
        fit_keypoint_offsets(lifted, lifted[:9])
    labels = lifted.copy()
    labels[0, 0, 0] = np.inf
    with pytest.raises(ValueError, match="finite"):
        fit_keypoint_offsets(lifted, labels)
    with pytest.raises(ValueError, match="points must be"):
        bone_frames(np.zeros((21, 2)))
    with pytest.raises(ValueError, match="must both be"):
        fit_pose_correction(lifted, lifted[:, :20])


def thumb_error(points: np.ndarray) -> np.ndarray:
    """A detector-like error that follows the pose: the thumb's joints pulled towards the index finger's tip by a
    share of their distance to it, seen in the palm's frame; (n, 21, 3) metres."""
    origin, rotation = palm_frame(points)
    local = np.einsum("nji,nkj->nki", rotation, points - origin[:, None])
    error = np.zeros_like(local)
    error[:, 1:5] = 0.25 * (local[:, 8:9] - local[:, 1:5])
    return np.einsum("nij,nkj->nki", rotation, error)


def test_an_error_that_follows_the_pose_is_learned_in_the_palm_frame():
    rng = np.random.default_rng(4)
    lifted = hands(300, rng)
    labels = lifted + thumb_error(lifted)
    held = hands(20, rng)
    target = held + thumb_error(held)
    before = np.linalg.norm(held - target, axis=-1)
    constant = fit_keypoint_offsets(lifted, labels)
    assert constant.pose is None
    learned = fit_keypoint_offsets(lifted, labels, pose=True)
    assert learned.pose is not None and learned.pose.frames_used == 300
    with_constant = np.linalg.norm(constant.apply(held) - target, axis=-1)[:, 1:5].mean()
    with_pose = np.linalg.norm(learned.apply(held) - target, axis=-1)[:, 1:5].mean()
    assert with_pose < 0.3 * with_constant, (before[:, 1:5].mean(), with_constant, with_pose)
    assert with_constant < before[:, 1:5].mean()
    assert learned.summary()["pose_frames"] == 300 and constant.summary()["pose_frames"] == 0
    # The same hand turned and moved is corrected by the same move, turned with it.
    turn, move = random_rotation(rng), np.array([0.1, -0.2, 0.4])
    np.testing.assert_allclose(learned.apply(held @ turn.T + move), learned.apply(held) @ turn.T + move, atol=1e-12)


def test_a_pose_unlike_the_labelled_ones_gets_less_of_the_correction():
    rng = np.random.default_rng(6)
    lifted = hands(60, rng)
    pose = fit_pose_correction(lifted, lifted + thumb_error(lifted))
    unshrunk = replace(pose, leverage=np.zeros_like(pose.leverage))
    near, far = hands(1, rng), 1.6 * hands(1, rng)  # a hand 1.6 times the labelled ones' size: far from their poses
    for hand, most in ((near, 1.0), (far, 0.2)):
        rotation = palm_frame(hand)[1][0]
        constant = pose.bias.reshape(21, 3) @ rotation.T  # the correction at the mean pose is not scaled
        full, shrunk = unshrunk.apply(hand)[0] - hand[0] - constant, pose.apply(hand)[0] - hand[0] - constant
        centred = ((hand[0] - hand[0, 0]) @ rotation).reshape(-1) - pose.mean
        scale = 1 / (1 + centred @ pose.leverage @ centred / POSE_LEVERAGE_SCALE)
        assert 0 < scale <= most, scale
        np.testing.assert_allclose(shrunk, scale * full, atol=1e-12)
        assert np.abs(full).max() > 1e-3


def test_the_pose_term_needs_enough_whole_frames_and_leaves_missing_points():
    rng = np.random.default_rng(5)
    lifted = hands(POSE_MIN_FRAMES + 5, rng)
    labels = lifted + thumb_error(lifted)
    lifted[:6, 12] = np.nan  # frames with a keypoint missing do not count
    assert fit_pose_correction(lifted, labels) is None
    assert fit_keypoint_offsets(lifted, labels, pose=True).pose is None
    pose = fit_pose_correction(lifted[1:], labels[1:], min_frames=POSE_MIN_FRAMES - 1)
    assert pose is not None and pose.frames_used == POSE_MIN_FRAMES - 1
    one = hands(1, rng)
    one[0, 16] = np.nan  # the ring tip: the others are corrected, it stays missing
    moved = pose.apply(one)
    assert np.isnan(moved[0, 16]).all() and np.isfinite(np.delete(moved[0], 16, axis=0)).all()
    assert not np.allclose(moved[0, 1:5], one[0, 1:5])
    one[0, 0] = np.nan  # no wrist: no palm frame, nothing moves
    np.testing.assert_array_equal(pose.apply(one), one)
