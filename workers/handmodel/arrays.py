"""The arrays that define a MANO-compatible hand model, whatever its source.

Both the official MANO pickle (loaded by `mano_loader`) and the built-in procedural hand (`builtin`)
produce a `HandModelArrays`; the torch layer (`layer.HandLayer`) only consumes it.

Glossary of dimension letters: V vertices, F faces, J = 16 joints, P = 135 pose-corrective inputs
(15 joints x 9 rotation-matrix entries), S = 10 shape coefficients.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workers.handmodel.keypoints import MANO_PARENTS, NUM_BETAS, NUM_JOINTS, NUM_POSE


class HandModelError(ValueError):
    """A hand model file or array set is malformed; the message names the field at fault."""


@dataclass(frozen=True)
class HandModelArrays:
    """Everything linear blend skinning needs, in metres, float64, rest pose = zero pose.

    Attributes:
        name: human-readable model name, e.g. "MANO_RIGHT.pkl" or "handloop-builtin v1".
        is_mano: True only for the official, licensed MANO files.
        side: "right" or "left".
        v_template: (V, 3) rest-pose vertices of the mean shape.
        shapedirs: (V, 3, S) shape blend-shape directions (metres per unit beta).
        posedirs: (V, 3, P) pose-corrective directions; input is (R - I) flattened per joint. May be 0.
        J_regressor: (J, V) dense joint regressor; rows sum to 1.
        weights: (V, J) skinning weights; rows sum to 1.
        parents: (J,) parent joint index, -1 for the root (MANO's kinematic tree).
        faces: (F, 3) int64 triangle indices, counter-clockwise seen from outside.
        hands_components: (45, 45) PCA pose basis, one component per row, most significant first.
        hands_mean: (45,) mean articulation in axis-angle (added unless flat_hand_mean).
        fingertip_vertex_ids: (5,) vertex ids of the tips: thumb, index, middle, ring, pinky.
        source_note: where the arrays came from, shown in the UI and exports.
    """

    name: str
    is_mano: bool
    side: str
    v_template: np.ndarray
    shapedirs: np.ndarray
    posedirs: np.ndarray
    J_regressor: np.ndarray
    weights: np.ndarray
    parents: np.ndarray
    faces: np.ndarray
    hands_components: np.ndarray
    hands_mean: np.ndarray
    fingertip_vertex_ids: np.ndarray
    source_note: str = ""
    extras: dict = field(default_factory=dict)

    @property
    def num_vertices(self) -> int:
        return int(self.v_template.shape[0])

    def validate(self) -> HandModelArrays:
        """Check shapes, finiteness and normalisation; raise HandModelError naming the field at fault."""
        V = self.v_template.shape[0] if self.v_template.ndim == 2 else -1
        expected = {
            "v_template": (V, 3),
            "shapedirs": (V, 3, NUM_BETAS),
            "posedirs": (V, 3, (NUM_JOINTS - 1) * 9),
            "J_regressor": (NUM_JOINTS, V),
            "weights": (V, NUM_JOINTS),
            "parents": (NUM_JOINTS,),
            "hands_components": (NUM_POSE, NUM_POSE),
            "hands_mean": (NUM_POSE,),
            "fingertip_vertex_ids": (5,),
        }
        if V <= 0 or self.v_template.shape[1:] != (3,):
            raise HandModelError(f"v_template must have shape (V, 3), got {self.v_template.shape}")
        for key, shape in expected.items():
            value = getattr(self, key)
            if tuple(value.shape) != shape:
                raise HandModelError(f"{key} must have shape {shape}, got {tuple(value.shape)}")
            if not np.all(np.isfinite(value)):
                raise HandModelError(f"{key} contains non-finite values")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise HandModelError(f"faces must have shape (F, 3), got {self.faces.shape}")
        if self.faces.min() < 0 or self.faces.max() >= V:
            raise HandModelError(f"faces index vertices outside 0..{V - 1}")
        if self.fingertip_vertex_ids.min() < 0 or self.fingertip_vertex_ids.max() >= V:
            raise HandModelError(f"fingertip_vertex_ids outside 0..{V - 1}")
        if tuple(int(p) for p in self.parents) != MANO_PARENTS:
            raise HandModelError(f"parents must be MANO's kinematic tree {MANO_PARENTS}")
        if not np.allclose(self.weights.sum(axis=1), 1.0, atol=1e-4):
            raise HandModelError("weights rows must sum to 1")
        if not np.allclose(self.J_regressor.sum(axis=1), 1.0, atol=1e-4):
            raise HandModelError("J_regressor rows must sum to 1")
        if self.side not in ("right", "left"):
            raise HandModelError(f"side must be 'right' or 'left', got {self.side!r}")
        return self
