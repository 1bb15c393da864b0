"""Which hand model made a fit, and its arrays in the API process (the mesh: tests/workers/handmodel/test_posed.py)."""

from __future__ import annotations

from backend.viewer.hand_mesh import hand_model_label, is_stand_in, load_arrays


def test_stand_in_is_named_as_such():
    assert is_stand_in("handloop-builtin v1") and is_stand_in("builtin")
    assert not is_stand_in("/models/MANO_RIGHT.pkl")
    assert hand_model_label("builtin") == "built-in stand-in hand, not MANO"
    assert hand_model_label("/m/MANO_RIGHT.pkl") == "MANO (MANO_RIGHT.pkl)"
    assert load_arrays("/m/MANO_RIGHT.pkl", None) is None  # no MANO here: no mesh rather than a wrong one
