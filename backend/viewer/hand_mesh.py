"""A fit's hand mesh from its parameters, in numpy.

Linear blend skinning written again here (the torch version is workers/handmodel/lbs.py) because the
API process must not import torch, and one forward pass of one hand is cheap in numpy (about a
millisecond). tests/backend/viewer/test_hand_mesh.py checks it against `HandLayer`.

theta (61,) follows docs/conventions.md: betas 10, articulation 45 (axis-angle, flat-hand mean), global
rotation 3 (about the wrist joint), translation 3 (metres).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from workers.handmodel.arrays import HandModelArrays
from workers.handmodel.keypoints import FREIHAND_FROM_MANO
from workers.handmodel.loading import load_hand_model

logger = logging.getLogger(__name__)

NUM_PARAMS = 61
STAND_IN_LABEL = "built-in stand-in hand, not MANO"


@dataclass(frozen=True, eq=False)
class HandMesh:
    """vertices (V, 3) float64 metres, world frame; faces (F, 3) int64; keypoints (21, 3) metres, world
    frame, FreiHAND order (regressed from this mesh)."""

    vertices: np.ndarray
    faces: np.ndarray
    keypoints: np.ndarray


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


def axis_angle_to_matrix(rotvecs: np.ndarray) -> np.ndarray:
    """Rodrigues: (N, 3) axis-angle radians -> (N, 3, 3)."""
    rotvecs = np.asarray(rotvecs, dtype=np.float64).reshape(-1, 3)
    angle = np.linalg.norm(rotvecs, axis=1)[:, None, None]
    small = angle < 1e-8
    safe = np.where(small, 1.0, angle)
    a = np.where(small, 1.0, np.sin(safe) / safe)
    b = np.where(small, 0.5, (1.0 - np.cos(safe)) / (safe * safe))
    x, y, z = rotvecs.T
    zero = np.zeros_like(x)
    K = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=1).reshape(-1, 3, 3)
    return np.eye(3)[None] + a * K + b * (K @ K)


def posed_mesh(arrays: HandModelArrays, params: np.ndarray) -> HandMesh:
    """Shape, pose and place the hand for theta (61,) (see the module docstring)."""
    theta = np.asarray(params, dtype=np.float64)
    if theta.shape != (NUM_PARAMS,) or not np.isfinite(theta).all():
        raise ValueError(f"params must be 61 finite numbers, got shape {theta.shape}")
    betas, pose, global_orient, transl = theta[:10], theta[10:55], theta[55:58], theta[58:61]
    V = arrays.v_template.shape[0]
    v_shaped = arrays.v_template + (arrays.shapedirs.reshape(V * 3, -1) @ betas).reshape(V, 3)
    joints = arrays.J_regressor @ v_shaped  # (J, 3) rest pose
    rot = axis_angle_to_matrix(np.concatenate([global_orient, pose]))  # (J, 3, 3)
    v_posed = v_shaped
    if np.any(arrays.posedirs):
        features = (rot[1:] - np.eye(3)).ravel()
        v_posed = v_shaped + (arrays.posedirs.reshape(V * 3, -1) @ features).reshape(V, 3)
    parents = [int(p) for p in arrays.parents]
    world = np.zeros((len(parents), 4, 4))
    for j, parent in enumerate(parents):  # parents precede children in MANO's tree
        local = np.eye(4)
        local[:3, :3] = rot[j]
        local[:3, 3] = joints[j] - (joints[parent] if parent >= 0 else 0.0)
        world[j] = local if parent < 0 else world[parent] @ local
    skinning = world.copy()
    skinning[:, :3, 3] -= np.einsum("jik,jk->ji", world[:, :3, :3], joints)  # act on rest-pose points
    blended = (arrays.weights @ skinning[:, :3, :].reshape(len(parents), 12)).reshape(V, 3, 4)
    vertices = np.einsum("vik,vk->vi", blended[:, :, :3], v_posed) + blended[:, :, 3] + transl
    tips = vertices[arrays.fingertip_vertex_ids]
    keypoints = np.concatenate([arrays.J_regressor @ vertices, tips])[list(FREIHAND_FROM_MANO)]
    return HandMesh(vertices, np.asarray(arrays.faces, dtype=np.int64), keypoints)
