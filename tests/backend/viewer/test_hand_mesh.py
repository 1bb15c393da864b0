"""Which hand model made a fit, its arrays and its stored mesh in the API process (posing: test_posed.py)."""

from __future__ import annotations

import numpy as np
import pytest

from backend.viewer.hand_mesh import fit_mesh, hand_model_label, is_stand_in, load_arrays
from workers.handmodel.params import HandParams
from workers.handmodel.posed import posed_mesh


def test_stand_in_is_named_as_such():
    assert is_stand_in("handloop-builtin v1") and is_stand_in("builtin")
    assert not is_stand_in("/models/MANO_RIGHT.pkl")
    assert hand_model_label("builtin") == "built-in stand-in hand, not MANO"
    assert hand_model_label("/m/MANO_RIGHT.pkl") == "MANO (MANO_RIGHT.pkl)"
    assert load_arrays("/m/MANO_RIGHT.pkl", None) is None  # no MANO here: no mesh rather than a wrong one


def test_a_fit_mesh_is_the_stored_one_and_only_fits_without_one_are_posed():
    arrays = load_arrays("handloop-builtin v1", None)
    theta = np.random.default_rng(0).normal(0, 0.2, 61)
    posed = posed_mesh(arrays, HandParams.from_theta(theta))
    stored = posed.vertices + np.array([0.05, 0.0, 0.0])  # not what the parameters pose: shown as stored
    mesh = fit_mesh(arrays, theta, stored.astype("<f4").tobytes())
    np.testing.assert_allclose(mesh.vertices, stored, atol=1e-6)
    np.testing.assert_allclose(mesh.keypoints, posed.keypoints + np.array([0.05, 0.0, 0.0]), atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, arrays.faces)
    legacy = fit_mesh(arrays, theta, None)  # recorded before revision 0012: posed from the parameters
    np.testing.assert_allclose(legacy.vertices, posed.vertices)
    with pytest.raises(ValueError, match="the stored mesh has 10 vertices"):
        fit_mesh(arrays, theta, np.zeros((10, 3), "<f4").tobytes())
