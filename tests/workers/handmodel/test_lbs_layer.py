"""The skinning chain and the layer against smplx's independent implementation of LBS."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from smplx.lbs import lbs as smplx_lbs

from tests.workers.handmodel.fake_arrays import random_hand_arrays
from workers.handmodel.keypoints import FREIHAND_FROM_MANO, MANO_PARENTS
from workers.handmodel.layer import HandLayer
from workers.handmodel.lbs import axis_angle_to_matrix


def smplx_reference(arrays, betas, full_pose):
    """smplx.lbs on the same arrays (posedirs reshaped to its (P, 3V) layout), float64."""
    t = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
    posedirs = t(arrays.posedirs).reshape(-1, 135).T
    return smplx_lbs(t(betas), t(full_pose), t(arrays.v_template), t(arrays.shapedirs), posedirs,
                     t(arrays.J_regressor), torch.as_tensor(MANO_PARENTS), t(arrays.weights))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_layer_matches_smplx_lbs(seed):
    arrays = random_hand_arrays(seed=seed)
    rng = np.random.default_rng(seed)
    B = 4
    betas = rng.normal(0, 1, (B, 10))
    pose = rng.normal(0, 0.6, (B, 45))
    orient = rng.normal(0, 1.0, (B, 3))
    transl = rng.normal(0, 0.3, (B, 3))
    layer = HandLayer(arrays, dtype=torch.float64)
    out = layer(torch.tensor(betas), torch.tensor(pose), torch.tensor(orient), torch.tensor(transl))
    ref_v, ref_j = smplx_reference(arrays, betas, np.concatenate([orient, pose], 1))
    assert torch.allclose(out.vertices, ref_v + torch.tensor(transl)[:, None], atol=1e-5)
    assert torch.allclose(out.joints, ref_j + torch.tensor(transl)[:, None], atol=1e-5)
    # smplx adds 1e-8 to rotation angles; the rest of the difference is rounding.
    assert (out.vertices - ref_v - torch.tensor(transl)[:, None]).abs().max() < 1e-7


def test_zero_pose_zero_shape_gives_template():
    arrays = random_hand_arrays()
    out = HandLayer(arrays, dtype=torch.float64)(batch_size=2)
    assert torch.allclose(out.vertices, torch.as_tensor(arrays.v_template).expand(2, -1, -1), atol=1e-12)


def test_keypoints_are_regressed_joints_and_tips_in_freihand_order():
    arrays = random_hand_arrays()
    layer = HandLayer(arrays, dtype=torch.float64)
    pose = torch.randn(3, 45, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 0.4
    out = layer(pose=pose)
    regressed = torch.einsum("jv,bvc->bjc", layer.J_regressor, out.vertices)
    tips = out.vertices[:, arrays.fingertip_vertex_ids]
    expected = torch.cat([regressed, tips], 1)[:, list(FREIHAND_FROM_MANO)]
    assert torch.allclose(out.keypoints, expected)
    # The wrist keypoint is the root joint; each fingertip keypoint is its tip vertex.
    assert torch.allclose(out.keypoints[:, 0], regressed[:, 0])
    assert torch.allclose(out.keypoints[:, 4], out.vertices[:, arrays.fingertip_vertex_ids[0]])
    assert torch.allclose(out.keypoints[:, 20], out.vertices[:, arrays.fingertip_vertex_ids[4]])


def test_pca_pose_and_hand_mean():
    arrays = random_hand_arrays()
    coeffs = torch.randn(2, 6, dtype=torch.float64)
    pca = HandLayer(arrays, use_pca=True, num_pca_comps=6, flat_hand_mean=False, dtype=torch.float64)
    aa = HandLayer(arrays, use_pca=False, flat_hand_mean=True, dtype=torch.float64)
    pose = coeffs @ torch.as_tensor(arrays.hands_components[:6]) + torch.as_tensor(arrays.hands_mean)
    assert torch.allclose(pca(pose=coeffs).vertices, aa(pose=pose).vertices, atol=1e-12)


def test_float32_and_gradients():
    arrays = random_hand_arrays()
    layer = HandLayer(arrays)
    pose = torch.zeros(1, 45, requires_grad=True)  # zero angle: the Taylor branch must give gradients
    out = layer(pose=pose)
    assert out.vertices.dtype == torch.float32
    out.keypoints.sum().backward()
    assert torch.isfinite(pose.grad).all() and pose.grad.abs().sum() > 0


def test_rodrigues_against_matrix_exponential():
    rot = torch.randn(50, 3, dtype=torch.float64) * 2
    rot[:5] *= 1e-5  # the small-angle series
    expected = torch.linalg.matrix_exp(torch.stack([
        torch.tensor([[0, -z, y], [z, 0, -x], [-y, x, 0]], dtype=torch.float64) for x, y, z in rot.tolist()
    ]))
    assert torch.allclose(axis_angle_to_matrix(rot), expected, atol=1e-12)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"betas": torch.zeros(2, 9)}, "betas must have shape"),
    ({"pose": torch.full((1, 45), float("nan"))}, "pose contains non-finite"),
    ({"transl": torch.zeros(1, 2)}, "transl must have shape"),
])
def test_bad_inputs_raise_clear_errors(kwargs, message):
    layer = HandLayer(random_hand_arrays())
    with pytest.raises(ValueError, match=message):
        layer(**kwargs)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA path: checked on a GPU machine")
def test_cuda_matches_cpu():
    arrays = random_hand_arrays()
    pose = torch.randn(2, 45, dtype=torch.float64) * 0.5
    cpu = HandLayer(arrays, dtype=torch.float64)(pose=pose).vertices
    gpu = HandLayer(arrays, dtype=torch.float64).cuda()(pose=pose.cuda()).vertices.cpu()
    assert torch.allclose(cpu, gpu, atol=1e-9)
