"""The fit's reduced hand model agrees with HandLayer, and its Jacobians with autodiff."""

from __future__ import annotations

import pytest
import torch
from torch.func import jacfwd

from tests.workers.handmodel.fake_arrays import random_hand_arrays
from workers.fitting.engine import farthest_point_ids
from workers.fitting.kinematics import FitKinematics
from workers.handmodel.layer import HandLayer


def _models(hand):
    return {"builtin": hand, "with pose correctives": random_hand_arrays(seed=3)}


@pytest.mark.parametrize("name", ["builtin", "with pose correctives"])
def test_matches_hand_layer(hand, name):
    arrays = _models(hand)[name]
    ids = farthest_point_ids(arrays.v_template, 64)
    kin = FitKinematics(arrays, ids, 45, torch.float64, torch.device("cpu"))
    assert kin.has_pose_correctives == (name != "builtin")
    layer = HandLayer(arrays, use_pca=True, num_pca_comps=45, flat_hand_mean=False, dtype=torch.float64)
    params = 0.5 * torch.randn(3, kin.num_params, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    out = layer(betas=params[:, 51:], pose=params[:, 6:51], global_orient=params[:, :3], transl=params[:, 3:6])
    geo = kin(params)
    assert torch.allclose(geo.keypoints, out.keypoints, atol=1e-12)
    assert torch.allclose(geo.silhouette_vertices, out.vertices[:, ids], atol=1e-12)
    assert torch.allclose(geo.articulation, out.full_pose[:, 3:], atol=1e-12)
    assert kin(params, with_vertices=False).silhouette_vertices is None


@pytest.mark.parametrize("name", ["builtin", "with pose correctives"])
def test_jacobian_matches_forward_mode_autodiff(hand, name):
    arrays = _models(hand)[name]
    ids = farthest_point_ids(arrays.v_template, 40)
    kin = FitKinematics(arrays, ids, 45, torch.float64, torch.device("cpu"))
    params = 0.4 * torch.randn(2, kin.num_params, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    active = torch.tensor([0, 2, 3, 5, 6, 17, 50, 51, 60])  # rotation, translation, PCA and shape columns
    jac = kin.jacobian(params, active)
    for points, derivative in ((lambda p: kin(p).keypoints, jac.d_keypoints),
                               (lambda p: kin(p).silhouette_vertices, jac.d_vertices)):
        full = jacfwd(points)(params)  # (B, N, 3, B, P)
        reference = torch.stack([full[b, :, :, b][..., active] for b in range(2)])
        assert torch.allclose(derivative, reference, rtol=0, atol=1e-6 * reference.abs().max())
    assert torch.allclose(jac.geometry.keypoints, kin(params).keypoints)
    assert torch.allclose(jac.rotation_probes[:, 0], kin(params).joint_rotations)
