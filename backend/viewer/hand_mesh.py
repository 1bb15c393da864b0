"""Which hand model made a fit, and its arrays in the API process (torch-free).

A fit's mesh is the one the worker stored with it (`fit_mesh`); only fits from before it was stored are posed
here, with the hand model's numpy face (`workers.handmodel.posed.posed_mesh`; parameters
`workers.handmodel.params.HandParams`, theta (61,), docs/conventions.md).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from workers.handmodel.arrays import HandModelArrays
from workers.handmodel.keypoints import FREIHAND_FROM_MANO
from workers.handmodel.lbs import keypoints_from_vertices
from workers.handmodel.loading import load_hand_model
from workers.handmodel.params import HandParams
from workers.handmodel.posed import HandMesh, posed_mesh

logger = logging.getLogger(__name__)

STAND_IN_LABEL = "built-in stand-in hand, not MANO"


def is_stand_in(model_file: str) -> bool:
    """Whether a fit's `model_file` names the built-in procedural hand rather than the licensed MANO.

    Workers record the model's name ("handloop-builtin v1") or file ("/path/MANO_RIGHT.pkl"); anything
    that does not name a MANO pickle is the stand-in."""
    name = model_file.lower()
    return "builtin" in name or "mano" not in name


def hand_model_label(model_file: str) -> str:
    return STAND_IN_LABEL if is_stand_in(model_file) else f"MANO ({Path(model_file).name})"


def fit_side(diagnostics: dict | None) -> str:
    """The hand a fit posed, as the fit job records it (diagnostics 'hand_side'); fits from before left
    hands were fitted are right hands."""
    side = (diagnostics or {}).get("hand_side")
    return "left" if side == "left" else "right"


def load_arrays(model_file: str, mano_path: Path | None, side: str = "right") -> HandModelArrays | None:
    """The arrays of the model (of this side) that made a fit, or None when this process cannot load them
    (a MANO fit but no HANDLOOP_MANO_PATH here)."""

    if is_stand_in(model_file):
        return load_hand_model(None, side)
    if mano_path is None:
        logger.warning("fit made with %s but HANDLOOP_MANO_PATH is unset here: no mesh", model_file)
        return None
    return load_hand_model(Path(mano_path), side)


def fit_mesh(arrays: HandModelArrays, params: Sequence[float], vertices_f32: bytes | None) -> HandMesh:
    """A fit's mesh: the vertices the worker stored with it (`Fit.vertices_f32`, little-endian float32 (V, 3),
    metres, world frame) with the model's faces and the keypoints regressed from them; only fits recorded
    before those were stored (revision 0012) are posed here from their parameters (61,). ValueError for
    stored vertices that are not this model's mesh, or parameters that cannot be posed."""
    if vertices_f32 is None:
        return posed_mesh(arrays, HandParams.from_theta(params))
    vertices = np.frombuffer(vertices_f32, dtype="<f4").astype(np.float64)
    if vertices.size != arrays.num_vertices * 3:
        raise ValueError(f"the stored mesh has {vertices.size / 3:g} vertices, the hand model {arrays.num_vertices}")
    vertices = vertices.reshape(-1, 3)
    keypoints = keypoints_from_vertices(vertices[None], arrays.J_regressor, np.asarray(arrays.fingertip_vertex_ids),
                                        np.asarray(FREIHAND_FROM_MANO))[0]
    return HandMesh(vertices, np.asarray(arrays.faces, dtype=np.int64), keypoints)
