"""Score-volume targets, read-out below voxel size, soft-argmax, and their confidence."""

from __future__ import annotations

import numpy as np
import torch

from workers.nets.losses import (
    gaussian_targets,
    grid_to_world,
    refined_argmax,
    scorevolume_loss,
    soft_argmax,
    softargmax_loss,
    world_to_grid,
)


def test_gaussian_target_peaks_at_one_on_the_keypoint():
    kp = torch.tensor([[[5.0, 7.0, 3.0]]])
    target = gaussian_targets(kp, 12, 2.0)
    assert target.shape == (1, 1, 12, 12, 12)
    assert float(target[0, 0, 5, 7, 3]) == 1.0
    assert float(target.max()) == 1.0
    assert abs(float(target[0, 0, 7, 7, 3]) - float(torch.exp(torch.tensor(-0.5)))) < 1e-6  # 2 voxels = 1 sigma


def test_refined_argmax_recovers_subvoxel_positions_and_confidence():
    kp = torch.tensor([[[5.3, 7.8, 3.45], [2.0, 9.1, 6.6]]])
    scores = 0.9 * gaussian_targets(kp, 12, 2.0)
    found, confidence = refined_argmax(scores)
    torch.testing.assert_close(found, kp, atol=1e-3, rtol=0)
    assert torch.all(confidence <= 0.9 + 1e-6) and torch.all(confidence > 0.8)


def test_soft_argmax_of_a_sharp_peak_and_zero_losses_at_the_truth():
    kp = torch.tensor([[[4.0, 6.0, 8.0]]])
    target = gaussian_targets(kp, 12, 2.0)
    found, confidence = soft_argmax(40 * target)
    torch.testing.assert_close(found, kp, atol=1e-2, rtol=0)
    assert 0 < float(confidence) <= 1
    assert float(scorevolume_loss(target, target)) == 0.0
    assert float(softargmax_loss(40 * target, kp)) < 0.05


def test_world_grid_round_trip():
    pts = torch.randn(3, 21, 3) * 0.1
    centers = torch.randn(3, 3) * 0.05
    back = grid_to_world(world_to_grid(pts, centers, 16, 0.4), centers, 16, 0.4)
    torch.testing.assert_close(back, pts)


def test_heatmap_2d_loss_is_smallest_for_maps_peaked_at_the_keypoints():
    from workers.nets.losses import gaussian_targets_2d, heatmap_2d_loss, peak_normalised

    kp = torch.tensor([[[[3.0, 9.0], [11.5, 4.0]]]])  # (B=1, C=1, K=2, 2) (u, v)
    weights = torch.ones(1, 1, 2)
    good = 8 * gaussian_targets_2d(kp, 16, 1.0)
    shifted = 8 * gaussian_targets_2d(kp + 3, 16, 1.0)
    assert float(heatmap_2d_loss(good, kp, weights, 1.0)) < float(heatmap_2d_loss(shifted, kp, weights, 1.0))
    assert float(heatmap_2d_loss(shifted, kp, torch.zeros(1, 1, 2), 1.0)) == 0.0  # unlabelled: no loss
    peak = peak_normalised(good)
    assert float(peak.amax()) == 1.0 and peak[0, 0, 0, 9, 3] == 1.0  # indexed [v, u]


def test_world_grid_round_trip_in_a_rotated_grid():
    from workers.nets.data import random_rotation

    rotation = torch.as_tensor(np.stack([random_rotation(np.random.default_rng(s)) for s in range(3)]),
                               dtype=torch.float32)
    pts = torch.randn(3, 21, 3) * 0.1
    centers = torch.randn(3, 3) * 0.05
    grid = world_to_grid(pts, centers, 16, 0.4, rotation)
    torch.testing.assert_close(grid_to_world(grid, centers, 16, 0.4, rotation), pts, atol=1e-5, rtol=0)
    # Distances are preserved: the grid is only turned, voxels stay 2.5 cm.
    d_world = (pts[:, 0] - pts[:, 1]).norm(dim=-1)
    d_grid = (grid[:, 0] - grid[:, 1]).norm(dim=-1) * 0.4 / 16
    torch.testing.assert_close(d_world, d_grid, atol=1e-5, rtol=0)
