"""The hand model's numpy face: a posed mesh from `HandParams`, torch-free (the API process uses it).

The same forward pass as the torch face `HandLayer` (workers/handmodel/lbs.py's functions, called here
with numpy arrays); tests/workers/handmodel/test_posed.py holds the two equal. One hand in numpy is cheap
(about a millisecond).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.handmodel.arrays import HandModelArrays
from workers.handmodel.keypoints import FREIHAND_FROM_MANO
from workers.handmodel.lbs import keypoints_from_vertices, lbs
from workers.handmodel.params import HandParams


@dataclass(frozen=True, eq=False)
class HandMesh:
    """vertices (V, 3) float64 metres, world frame; faces (F, 3) int64; keypoints (21, 3) metres, world
    frame, FreiHAND order (regressed from this mesh)."""

    vertices: np.ndarray
    faces: np.ndarray
    keypoints: np.ndarray


def posed_mesh(arrays: HandModelArrays, params: HandParams | np.ndarray, *, mean_pose: bool = False) -> HandMesh:
    """Shape, pose and place one hand.

    Args:
        arrays: the hand model.
        params: HandParams of one hand, or its theta (61,) (workers/handmodel/params.py).
        mean_pose: if True, `params.pose` is relative to the model's `hands_mean` (MANO's
            flat_hand_mean=False, FreiHAND's convention) rather than to the flat hand.
    Returns:
        HandMesh, metres, world frame.
    """
    if not isinstance(params, HandParams):
        params = HandParams.from_theta(params)
    if params.betas.shape != (10,):
        raise ValueError(f"posed_mesh poses one hand: params must be (61,), got betas {params.betas.shape}")
    pose = params.pose + arrays.hands_mean if mean_pose else params.pose
    full_pose = np.concatenate([params.global_orient, pose])[None]  # (1, 48)
    posedirs = arrays.posedirs if np.any(arrays.posedirs) else None
    vertices, _ = lbs(params.betas[None], full_pose, arrays.v_template, arrays.shapedirs, posedirs,
                      arrays.J_regressor, tuple(int(p) for p in arrays.parents), arrays.weights)
    vertices = vertices + params.transl
    keypoints = keypoints_from_vertices(vertices, arrays.J_regressor, np.asarray(arrays.fingertip_vertex_ids),
                                        np.asarray(FREIHAND_FROM_MANO))
    return HandMesh(vertices[0], np.asarray(arrays.faces, dtype=np.int64), keypoints[0])
