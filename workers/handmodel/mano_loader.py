"""Load the official, licensed MANO_RIGHT.pkl / MANO_LEFT.pkl without chumpy installed.

The MANO pickles (Python 2) hold some arrays as chumpy `Ch` objects and the joint regressor as a
scipy sparse matrix. A restricted unpickler maps chumpy classes to a stand-in that keeps only the
pickled state, from which the array value (`x`) is read; every other global must be on an allow-list,
so a malicious pickle cannot run code.
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse

try:  # numpy >= 2
    from numpy._core import multiarray as _multiarray
except ImportError:  # pragma: no cover - numpy 1.x
    from numpy.core import multiarray as _multiarray

from workers.handmodel.arrays import HandModelArrays, HandModelError
from workers.handmodel.keypoints import MANO_FINGERTIP_VERTEX_IDS

MANO_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f",
             "hands_components", "hands_mean")


class ChumpyStandIn:
    """Receives a chumpy object's pickled state (its __dict__ minus caches)."""

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.state = state

    def value(self, key: str) -> np.ndarray:
        if not isinstance(getattr(self, "state", None), dict) or "x" not in self.state:
            raise HandModelError(f"MANO field '{key}' is a chumpy expression, not a stored array; "
                                 "re-save the file with plain arrays (e.g. smplx's tools/clean_ch.py)")
        return np.asarray(_plain(self.state["x"], key), dtype=np.float64)


_SPARSE = {name: getattr(scipy.sparse, name) for name in ("csc_matrix", "csr_matrix", "coo_matrix")}
_ALLOWED: dict[tuple[str, str], Any] = {
    ("numpy.core.multiarray", "_reconstruct"): _multiarray._reconstruct,
    ("numpy._core.multiarray", "_reconstruct"): _multiarray._reconstruct,
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
    ("numpy.core.multiarray", "scalar"): _multiarray.scalar,
    ("numpy._core.multiarray", "scalar"): _multiarray.scalar,
    ("copy_reg", "_reconstructor"): __import__("copyreg")._reconstructor,
    ("copyreg", "_reconstructor"): __import__("copyreg")._reconstructor,
    ("__builtin__", "object"): object,
    ("builtins", "object"): object,
    ("__builtin__", "set"): set,
    ("builtins", "set"): set,
    ("_codecs", "encode"): __import__("codecs").encode,  # bytes in protocol-2 pickles written by Python 3
}


class _MANOUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        if module.startswith("chumpy"):
            return ChumpyStandIn
        if module.startswith("scipy.sparse") and name in _SPARSE:
            return _SPARSE[name]
        if (module, name) in _ALLOWED:
            return _ALLOWED[(module, name)]
        raise HandModelError(f"MANO file refers to an unexpected Python object {module}.{name}")


def _plain(value: Any, key: str) -> Any:
    """Turn a chumpy stand-in or sparse matrix into a dense numpy array; leave arrays as they are."""
    if isinstance(value, ChumpyStandIn):
        return value.value(key)
    if scipy.sparse.issparse(value):
        return np.asarray(value.todense())
    return value


def read_mano_pickle(path: Path) -> dict[str, Any]:
    """The raw dictionary of a MANO pickle with chumpy and sparse values made plain numpy arrays."""
    path = Path(path)
    try:
        with path.open("rb") as handle:
            data = _MANOUnpickler(handle, encoding="latin1").load()
    except FileNotFoundError:
        raise HandModelError(f"{path}: MANO file not found") from None
    except HandModelError as exc:
        raise HandModelError(f"{path}: {exc}") from None
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError) as exc:
        raise HandModelError(f"{path}: not a readable MANO pickle ({exc})") from None
    if not isinstance(data, dict):
        raise HandModelError(f"{path}: expected a dictionary, got {type(data).__name__}")
    missing = [k for k in MANO_KEYS if k not in data]
    if missing:
        raise HandModelError(f"{path}: missing MANO field(s) {missing}")
    try:
        return {k: _plain(v, k) for k, v in data.items()}
    except HandModelError as exc:
        raise HandModelError(f"{path}: {exc}") from None


def load_mano(path: Path, side: str | None = None) -> HandModelArrays:
    """Read MANO_RIGHT.pkl / MANO_LEFT.pkl into `HandModelArrays` (validated).

    Args:
        path: the pickle, or a folder holding MANO_RIGHT.pkl and/or MANO_LEFT.pkl.
        side: "right" or "left"; inferred from the file name when None (default right).
    """
    path = Path(path)
    if path.is_dir():
        side = side or "right"
        path = path / f"MANO_{side.upper()}.pkl"
    elif side is None:
        side = "left" if "left" in path.name.lower() else "right"
    raw = read_mano_pickle(path)
    kintree = np.asarray(raw["kintree_table"], dtype=np.int64)
    parents = kintree[0].copy()
    parents[0] = -1  # MANO stores 2**32 - 1 for the root
    v_template = np.asarray(raw["v_template"], dtype=np.float64)
    posedirs = np.asarray(raw["posedirs"], dtype=np.float64)
    try:
        arrays = HandModelArrays(
            name=path.name,
            is_mano=True,
            side=side,
            v_template=v_template,
            shapedirs=np.asarray(raw["shapedirs"], dtype=np.float64),
            posedirs=posedirs.reshape(v_template.shape[0], 3, -1),
            J_regressor=np.asarray(raw["J_regressor"], dtype=np.float64),
            weights=np.asarray(raw["weights"], dtype=np.float64),
            parents=parents,
            faces=np.asarray(raw["f"], dtype=np.int64),
            hands_components=np.asarray(raw["hands_components"], dtype=np.float64),
            hands_mean=np.asarray(raw["hands_mean"], dtype=np.float64).reshape(-1),
            fingertip_vertex_ids=np.asarray(MANO_FINGERTIP_VERTEX_IDS, dtype=np.int64),
            source_note=f"MANO hand model ({path.name}), licensed by the Max Planck Society",
        )
        return arrays.validate()
    except (HandModelError, ValueError) as exc:
        raise HandModelError(f"{path}: {exc}") from None
