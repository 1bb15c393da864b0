"""The MANO loader reads a pickle written in the real MANO structure, chumpy objects included,
without chumpy installed."""

from __future__ import annotations

import pickle
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse
import torch

from tests.workers.handmodel.fake_arrays import random_hand_arrays
from workers.handmodel.arrays import HandModelError
from workers.handmodel.keypoints import MANO_FINGERTIP_VERTEX_IDS, MANO_PARENTS
from workers.handmodel.layer import HandLayer
from workers.handmodel.mano_loader import load_mano


def _fake_chumpy_module() -> types.ModuleType:
    """A module named chumpy.ch whose Ch pickles like chumpy's (state = __dict__ without caches)."""
    module = types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x = np.asarray(x, dtype=np.float64)
            self._dirty_vars = set()
            self._itr = None
            self._parents = {}
            self._cache = {"r": None}
            self._depends_on_deps = {}

        def __getstate__(self):
            state = dict(self.__dict__)
            del state["_parents"], state["_cache"]
            return state

    Ch.__module__ = "chumpy.ch"
    Ch.__qualname__ = "Ch"
    module.Ch = Ch
    return module


def write_fake_mano(path: Path, num_vertices: int = 778, chumpy_expression: bool = False) -> dict:
    """Write a MANO_RIGHT.pkl-shaped pickle (protocol 2, as MANO's Python 2 files) and return its arrays."""
    arrays = random_hand_arrays(num_vertices=num_vertices, seed=3)
    ch = _fake_chumpy_module()
    sys.modules["chumpy"] = types.ModuleType("chumpy")
    sys.modules["chumpy.ch"] = ch
    try:
        kintree = np.array([[2**32 - 1, *MANO_PARENTS[1:]], list(range(16))], dtype=np.int64)
        shapedirs = ch.Ch(arrays.shapedirs)
        if chumpy_expression:
            del shapedirs.x
            shapedirs.a = ch.Ch(arrays.shapedirs)
        data = {
            "hands_componentsl": arrays.hands_components,
            "hands_meanl": arrays.hands_mean,
            "hands_components": arrays.hands_components,
            "hands_mean": arrays.hands_mean,
            "hands_coeffs": np.zeros((10, 45)),
            "v_template": arrays.v_template,
            "shapedirs": shapedirs,
            "posedirs": arrays.posedirs,
            "J_regressor": scipy.sparse.csc_matrix(arrays.J_regressor),
            "weights": ch.Ch(arrays.weights),
            "kintree_table": kintree,
            "f": arrays.faces.astype(np.uint32),
            "J": np.zeros((16, 3)),
            "bs_style": "lbs",
            "bs_type": "lrotmin",
        }
        path.write_bytes(pickle.dumps(data, protocol=2))
    finally:
        del sys.modules["chumpy.ch"], sys.modules["chumpy"]
    return {"arrays": arrays}


def test_loads_real_structure_without_chumpy(tmp_path):
    pytest.importorskip("scipy")
    assert "chumpy" not in sys.modules
    written = write_fake_mano(tmp_path / "MANO_RIGHT.pkl")["arrays"]
    model = load_mano(tmp_path)  # a folder: picks MANO_RIGHT.pkl
    assert model.is_mano and model.side == "right" and model.name == "MANO_RIGHT.pkl"
    assert np.array_equal(model.shapedirs, written.shapedirs)
    assert np.array_equal(model.weights, written.weights)
    assert np.allclose(model.J_regressor, written.J_regressor)
    assert tuple(model.parents) == MANO_PARENTS
    assert tuple(model.fingertip_vertex_ids) == MANO_FINGERTIP_VERTEX_IDS
    pose = torch.randn(2, 45, dtype=torch.float64) * 0.3
    loaded = HandLayer(model, dtype=torch.float64)(pose=pose).vertices
    direct = HandLayer(written, dtype=torch.float64)(pose=pose).vertices
    assert torch.allclose(loaded, direct)


def test_chumpy_expression_is_refused_with_a_hint(tmp_path):
    write_fake_mano(tmp_path / "MANO_RIGHT.pkl", chumpy_expression=True)
    with pytest.raises(HandModelError, match="'shapedirs' is a chumpy expression"):
        load_mano(tmp_path / "MANO_RIGHT.pkl")


def test_unexpected_global_is_refused(tmp_path):
    class Evil:
        def __reduce__(self):
            return (print, ("pwned",))

    (tmp_path / "MANO_RIGHT.pkl").write_bytes(pickle.dumps({"x": Evil()}, protocol=2))
    with pytest.raises(HandModelError, match=r"unexpected Python object (__builtin__|builtins)\.print"):
        load_mano(tmp_path / "MANO_RIGHT.pkl")


@pytest.mark.parametrize(("content", "message"), [
    (b"not a pickle", "not a readable MANO pickle"),
    (pickle.dumps([1, 2, 3]), "expected a dictionary"),
    (pickle.dumps({"v_template": np.zeros((3, 3))}), "missing MANO field"),
])
def test_malformed_files(tmp_path, content, message):
    path = tmp_path / "MANO_RIGHT.pkl"
    path.write_bytes(content)
    with pytest.raises(HandModelError, match=message):
        load_mano(path)


def test_missing_file_names_the_path(tmp_path):
    with pytest.raises(HandModelError, match=r"MANO_LEFT\.pkl: MANO file not found"):
        load_mano(tmp_path, side="left")
