"""Unprojection puts a view's feature at the voxel of the 3D point that projects there."""

from __future__ import annotations

import numpy as np
import torch

from workers.geometry.projection import project_points, stack_cameras
from workers.geometry.rig import default_rig
from workers.nets.data import crop_views
from workers.nets.unproject import unproject_features, voxel_centers


def _delta_features(cameras, point, center, crop_px=32, feat_px=32, radius=0.15):
    """Crops' intrinsics and one-hot feature maps lit at the pixel where `point` projects."""
    images = [np.zeros((c.height, c.width, 3), np.uint8) for c in cameras]
    _, K_crop, valid, _ = crop_views(images, cameras, center, crop_px, radius)
    features = torch.zeros(1, len(cameras), 1, feat_px, feat_px)
    for c, cam in enumerate(cameras):
        px, _ = project_points(point[None], [cam])
        uv = (K_crop[c] @ np.linalg.inv(cam.K) @ np.append(px[0, 0], 1.0))[:2]  # distortion-free K change
        col, row = np.floor((uv + 0.5) * feat_px / crop_px).astype(int)
        features[0, c, 0, row, col] = 1.0
    return features, torch.as_tensor(K_crop[None], dtype=torch.float32), valid


def test_feature_lands_at_the_points_voxel():
    cameras = default_rig(96)
    center = np.array([0.01, -0.02, 0.03])
    N, side = 16, 0.4
    voxels = voxel_centers(torch.as_tensor(center[None], dtype=torch.float32), N, side)[0].numpy()
    target = (11, 4, 7)
    point = voxels[target].astype(np.float64)
    features, K_crop, valid = _delta_features(cameras, point, center)
    assert valid.all()
    cams = stack_cameras(cameras)
    volume = unproject_features(features, K_crop, cams["dist"], cams["R"], cams["t"],
                                torch.as_tensor(center[None], dtype=torch.float32), N, side, image_px=32)
    assert volume.shape == (1, 1, N, N, N)
    v = volume[0, 0]
    assert np.unravel_index(int(v.argmax()), v.shape) == target
    assert float(v[target]) > 0.5  # every view agrees on this voxel


def test_voxels_behind_a_camera_or_outside_its_crop_contribute_nothing():
    cameras = default_rig(96)[:1]
    cams = stack_cameras(cameras)
    center = np.zeros(3)
    _, K_crop, _, _ = crop_views([np.zeros((cameras[0].height, cameras[0].width, 3), np.uint8)], cameras, center, 16,
                                 0.05)
    features = torch.ones(1, 1, 2, 16, 16)
    volume = unproject_features(features, torch.as_tensor(K_crop[None], dtype=torch.float32), cams["dist"],
                                cams["R"], cams["t"], torch.zeros(1, 3), 8, 0.4, image_px=16)
    # The crop covers +-5 cm around the centre: an outer voxel off the line of sight falls outside it.
    assert float(volume[0, 0, 7, 0, 0]) == 0.0 and float(volume[0, 0, 3, 3, 3]) > 0.9
    # The same camera turned around (180 degrees about its y axis) has the grid behind it.
    flip = torch.diag(torch.tensor([-1.0, 1.0, -1.0]))
    volume = unproject_features(features, torch.as_tensor(K_crop[None], dtype=torch.float32), cams["dist"],
                                flip @ cams["R"], cams["t"] @ flip, torch.zeros(1, 3), 8, 0.4, image_px=16)
    assert float(volume.abs().max()) == 0.0


def test_crop_intrinsics_map_projections_into_the_crop():
    cameras = default_rig(128)
    center = np.array([0.0, 0.0, 0.0])
    points = np.array([[0.02, -0.03, 0.01], [-0.05, 0.04, 0.02]])
    images = [np.zeros((c.height, c.width, 3), np.uint8) for c in cameras]
    _, K_crop, _, _ = crop_views(images, cameras, center, 64, 0.13)
    from workers.nets.unproject import project_batched

    cams = stack_cameras(cameras, dtype=torch.float64)
    uv, _ = project_batched(torch.as_tensor(points[None]), torch.as_tensor(K_crop[None]), cams["dist"], cams["R"],
                            cams["t"])
    full, _ = project_points(points, cameras)
    for c, cam in enumerate(cameras):
        A = K_crop[c] @ np.linalg.inv(cam.K)
        expected = (A[:2, :2] @ full[c].T).T + A[:2, 2]
        np.testing.assert_allclose(uv[0, c].numpy(), expected, atol=1e-6)


def test_feature_lands_at_the_points_voxel_in_a_rotated_grid():
    from workers.nets.data import random_rotation
    from workers.nets.losses import world_to_grid

    cameras = default_rig(96)
    center = np.array([0.01, -0.02, 0.03])
    N, side = 16, 0.4
    rotation = torch.as_tensor(random_rotation(np.random.default_rng(4))[None], dtype=torch.float32)
    voxels = voxel_centers(torch.as_tensor(center[None], dtype=torch.float32), N, side, rotation)[0].numpy()
    target = (10, 5, 6)
    point = voxels[target].astype(np.float64)
    # The voxel's index is what world_to_grid gives for its centre.
    grid = world_to_grid(torch.as_tensor(point[None, None], dtype=torch.float32),
                         torch.as_tensor(center[None], dtype=torch.float32), N, side, rotation)
    np.testing.assert_allclose(grid[0, 0].numpy(), target, atol=1e-3)
    features, K_crop, _ = _delta_features(cameras, point, center)
    cams = stack_cameras(cameras)
    volume = unproject_features(features, K_crop, cams["dist"], cams["R"], cams["t"],
                                torch.as_tensor(center[None], dtype=torch.float32), N, side, image_px=32,
                                grid_rotation=rotation)
    v = volume[0, 0]
    assert np.unravel_index(int(v.argmax()), v.shape) == target


def test_per_frame_camera_subsets_match_the_full_rig():
    """Training feeds each frame a random subset of the views: indexing the rig per frame must give the
    same volume as passing those cameras alone."""
    cameras = default_rig(96)
    center = np.array([0.0, 0.01, -0.02])
    point = center + np.array([0.03, -0.02, 0.01])
    features, K_crop, _ = _delta_features(cameras, point, center)
    cams = stack_cameras(cameras)
    subset = torch.tensor([[0, 2, 5, 7]])
    a = unproject_features(features[:, subset[0]], K_crop[:, subset[0]], cams["dist"][subset], cams["R"][subset],
                           cams["t"][subset], torch.as_tensor(center[None], dtype=torch.float32), 16, 0.4, 32)
    sub_cams = stack_cameras([cameras[i] for i in subset[0].tolist()])
    b = unproject_features(features[:, subset[0]], K_crop[:, subset[0]], sub_cams["dist"], sub_cams["R"],
                           sub_cams["t"], torch.as_tensor(center[None], dtype=torch.float32), 16, 0.4, 32)
    torch.testing.assert_close(a, b)


def _grid_sample_reference(features, K, dist, R, t, center, N, side, image_px, view_valid=None):
    """The straightforward unprojection: grid_sample per view (align_corners=False, zero padding), then the
    average over the views that see each voxel."""
    import torch.nn.functional as nnf

    from workers.nets.unproject import project_batched

    B, C, F, h, w = features.shape
    points = voxel_centers(center, N, side).reshape(B, N**3, 3)
    pixels, depth = project_batched(points, K, dist, R, t)
    grid = (2 * pixels + 1) / image_px - 1
    inside = (depth > 1e-3) & (grid.abs() <= 1).all(dim=-1)
    if view_valid is not None:
        inside = inside & view_valid[:, :, None]
    sampled = nnf.grid_sample(features.reshape(B * C, F, h, w), grid.reshape(B * C, 1, N**3, 2), mode="bilinear",
                              padding_mode="zeros", align_corners=False).reshape(B, C, F, N**3)
    sampled = sampled * inside[:, :, None, :].to(features.dtype)
    count = inside.sum(dim=1).to(features.dtype)
    return (sampled.sum(dim=1) / count.clamp(min=1)[:, None, :]).reshape(B, F, N, N, N)


def test_unprojection_equals_grid_sample_and_its_gradient():
    """The embedding-bag unprojection is bilinear sampling plus the view average, values and gradients."""
    cameras = default_rig(96)
    cams = stack_cameras(cameras)
    rng = np.random.default_rng(0)
    centers = rng.normal(0, 0.03, (2, 3))
    K = np.stack([crop_views([np.zeros((c.height, c.width, 3), np.uint8) for c in cameras], cameras, ctr, 32,
                             0.12)[1] for ctr in centers])
    K = torch.as_tensor(K, dtype=torch.float32)
    center = torch.as_tensor(centers, dtype=torch.float32)
    valid = torch.ones(2, len(cameras), dtype=torch.bool)
    valid[1, 3] = False
    features = torch.randn(2, len(cameras), 5, 8, 8, requires_grad=True)
    args = (K, cams["dist"], cams["R"], cams["t"], center, 12, 0.4, 32)
    ours = unproject_features(features, *args, view_valid=valid)
    reference = _grid_sample_reference(features, *args, view_valid=valid)
    torch.testing.assert_close(ours, reference, atol=1e-5, rtol=1e-5)
    weights = torch.randn_like(reference)
    (grad_ours,) = torch.autograd.grad((ours * weights).sum(), features)
    (grad_ref,) = torch.autograd.grad((reference * weights).sum(), features)
    torch.testing.assert_close(grad_ours, grad_ref, atol=1e-5, rtol=1e-5)
    assert float(grad_ours[1, 3].abs().max()) == 0.0  # the invalid view gets no gradient
