"""The numpy mesh of a fit matches the torch HandLayer (the reference) for random parameters."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from backend.viewer.hand_mesh import axis_angle_to_matrix, hand_model_label, is_stand_in, load_arrays, posed_mesh
from workers.handmodel.layer import HandLayer


@pytest.fixture(scope="module")
def arrays():
    return load_arrays("handloop-builtin v1", None)


def test_rodrigues_matches_the_torch_layer():
    from workers.handmodel.lbs import axis_angle_to_matrix as reference

    rotvecs = np.random.default_rng(0).normal(size=(50, 3))
    rotvecs[0] = 0.0
    rotvecs[1] = 1e-9
    np.testing.assert_allclose(axis_angle_to_matrix(rotvecs), reference(torch.as_tensor(rotvecs)).numpy(),
                               atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_posed_mesh_matches_hand_layer(arrays, seed):
    rng = np.random.default_rng(seed)
    theta = np.concatenate([rng.normal(0, 1, 10), rng.normal(0, 0.3, 45), rng.normal(0, 1.5, 3),
                            rng.normal(0, 0.2, 3)])
    mesh = posed_mesh(arrays, theta)
    layer = HandLayer(arrays, flat_hand_mean=True, dtype=torch.float64)
    t = torch.as_tensor(theta)[None]
    out = layer(betas=t[:, :10], pose=t[:, 10:55], global_orient=t[:, 55:58], transl=t[:, 58:61])
    np.testing.assert_allclose(mesh.vertices, out.vertices[0].numpy(), atol=1e-9)
    np.testing.assert_allclose(mesh.keypoints, out.keypoints[0].numpy(), atol=1e-9)
    assert mesh.faces.shape == tuple(arrays.faces.shape)


def test_bad_params_are_refused(arrays):
    with pytest.raises(ValueError, match="61 finite"):
        posed_mesh(arrays, np.zeros(60))
    theta = np.zeros(61)
    theta[3] = np.nan
    with pytest.raises(ValueError, match="61 finite"):
        posed_mesh(arrays, theta)


def test_stand_in_is_named_as_such():
    assert is_stand_in("handloop-builtin v1") and is_stand_in("builtin")
    assert not is_stand_in("/models/MANO_RIGHT.pkl")
    assert hand_model_label("builtin") == "built-in stand-in hand, not MANO"
    assert hand_model_label("/m/MANO_RIGHT.pkl") == "MANO (MANO_RIGHT.pkl)"
    assert load_arrays("/m/MANO_RIGHT.pkl", None) is None  # no MANO here: no mesh rather than a wrong one
