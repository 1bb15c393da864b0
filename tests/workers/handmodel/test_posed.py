"""One forward pass, two faces: the numpy mesh (`posed_mesh`, the API's) equals the torch `HandLayer`, and
`HandParams` round-trips the 61-value vector."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from tests.workers.handmodel.fake_arrays import random_hand_arrays
from workers.geometry.rotation import axis_angle_to_matrix
from workers.handmodel.layer import HandLayer
from workers.handmodel.loading import load_hand_model
from workers.handmodel.params import NUM_PARAMS, HandParams
from workers.handmodel.posed import posed_mesh


def _theta(rng: np.random.Generator) -> np.ndarray:
    return np.concatenate([rng.normal(0, 1, 10), rng.normal(0, 0.3, 45), rng.normal(0, 1.5, 3), rng.normal(0, 0.2, 3)])


def test_hand_params_round_trip_the_61_vector_in_its_documented_layout():
    theta = np.arange(NUM_PARAMS, dtype=np.float64)
    params = HandParams.from_theta(theta)
    assert params.betas.tolist() == list(range(10)) and params.pose.tolist() == list(range(10, 55))
    assert params.global_orient.tolist() == [55, 56, 57] and params.transl.tolist() == [58, 59, 60]
    np.testing.assert_array_equal(params.to_theta(), theta)
    np.testing.assert_array_equal(params.full_pose, np.concatenate([theta[55:58], theta[10:55]]))
    batch = HandParams.from_theta(np.stack([theta, theta + 1]))
    assert batch.betas.shape == (2, 10) and batch.transl.shape == (2, 3)
    np.testing.assert_array_equal(batch.to_theta()[1], theta + 1)
    assert HandParams.zeros(3).pose.shape == (3, 45)


@pytest.mark.parametrize("bad", [np.zeros(60), np.zeros((2, 62)), np.array([np.nan] * 61), np.float64(1.0)])
def test_hand_params_refuse_a_malformed_vector_naming_the_layout(bad):
    with pytest.raises(ValueError, match=r"61 finite numbers .*betas 10, pose 45"):
        HandParams.from_theta(bad)


def test_rodrigues_is_one_function_for_numpy_and_torch_and_matches_scipy():
    rotvecs = np.random.default_rng(0).normal(size=(50, 3))
    rotvecs[0] = 0.0
    rotvecs[1] = 1e-9
    numpy_face = axis_angle_to_matrix(rotvecs)
    assert isinstance(numpy_face, np.ndarray)
    np.testing.assert_allclose(numpy_face, axis_angle_to_matrix(torch.as_tensor(rotvecs)).numpy(), atol=1e-15)
    np.testing.assert_allclose(numpy_face, Rotation.from_rotvec(rotvecs).as_matrix(), atol=1e-12)


@pytest.mark.parametrize(("arrays", "seed"), [("builtin", 0), ("builtin", 1), ("correctives", 2)])
def test_posed_mesh_matches_hand_layer(arrays, seed):
    arrays = load_hand_model(None) if arrays == "builtin" else random_hand_arrays(seed=seed)
    theta = _theta(np.random.default_rng(seed))
    mesh = posed_mesh(arrays, HandParams.from_theta(theta))
    out = HandLayer(arrays, flat_hand_mean=True, dtype=torch.float64).pose_params(HandParams.from_theta(theta[None]))
    np.testing.assert_allclose(mesh.vertices, out.vertices[0].numpy(), atol=1e-9)
    np.testing.assert_allclose(mesh.keypoints, out.keypoints[0].numpy(), atol=1e-9)
    assert mesh.faces.shape == tuple(arrays.faces.shape)
    # MANO's own convention (articulation relative to hands_mean) through the same numpy face.
    mean = posed_mesh(arrays, theta, mean_pose=True)
    layer_mean = HandLayer(arrays, flat_hand_mean=False, dtype=torch.float64)
    out = layer_mean.pose_params(HandParams.from_theta(theta[None]))
    np.testing.assert_allclose(mean.vertices, out.vertices[0].numpy(), atol=1e-9)


def test_posed_mesh_refuses_bad_params():
    arrays = random_hand_arrays()
    with pytest.raises(ValueError, match="61 finite"):
        posed_mesh(arrays, np.zeros(60))
    with pytest.raises(ValueError, match="poses one hand"):
        posed_mesh(arrays, np.zeros((2, 61)))
