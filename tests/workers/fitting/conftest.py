"""Synthetic frames with known parameters for fitting tests (built-in hand, default rig)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from workers.fitting.inputs import FrameObservations
from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig
from workers.handmodel.keypoints import SPARSE_KEYPOINTS
from workers.rendering import model_mask

TEST_SEED = 4242


@pytest.fixture(scope="session")
def hand():
    from workers.handmodel.builtin import build_builtin_hand

    return build_builtin_hand()


@pytest.fixture(scope="session")
def rig():
    return default_rig()


@pytest.fixture(scope="session")
def known_frames(hand, rig):
    """Two frames: (observations with exact sparse clicks in every view and exact masks, truth dict)."""
    from scipy.spatial.transform import Rotation

    from workers.handmodel import pose_sampler
    from workers.handmodel.layer import HandLayer

    rng = np.random.default_rng(TEST_SEED)
    poses = np.stack([pose_sampler.canonical_poses(hand)["count_2"], pose_sampler.sample(1, rng, hand)[0]])
    betas = np.clip(rng.normal(0, 0.7, (2, 10)), -1.5, 1.5)
    orient = Rotation.from_euler("xyz", [[20, -30, 10], [-40, 60, 150]], degrees=True).as_rotvec()
    layer = HandLayer(hand, dtype=torch.float64)
    out = layer(torch.tensor(betas), torch.tensor(poses), torch.tensor(orient), torch.zeros(2, 3))
    # Put the hand's centre at the rig's centre.
    transl = -out.vertices.mean(1).numpy()
    vertices = out.vertices.numpy() + transl[:, None]
    keypoints = out.keypoints.numpy() + transl[:, None]
    frames = []
    for b in range(2):
        pixels, _ = project_points(keypoints[b], rig)
        clicks = np.full((len(rig), 21, 2), np.nan)
        weights = np.zeros((len(rig), 21))
        clicks[:, SPARSE_KEYPOINTS] = pixels[:, SPARSE_KEYPOINTS]
        weights[:, SPARSE_KEYPOINTS] = 1.0
        masks = tuple(model_mask(vertices[b], hand.faces, cam) for cam in rig)
        frames.append(FrameObservations(clicks, weights, masks, masks_include_forearm=False))
    return frames, {"vertices": vertices, "keypoints": keypoints, "betas": betas, "poses": poses}
