"""The built-in procedural hand: a stand-in for the licensed MANO model with MANO's array interface.

Public API: `build_builtin_hand(side)`; see docs/hand-model.md ("Built-in hand") for the rest frame,
the meaning of the shape coefficients and how the mesh is generated.
"""

from workers.handmodel.builtin.build import GENERATOR_VERSION, MODEL_NAME, build_builtin_hand
from workers.handmodel.builtin.mirror import mirror_arrays
from workers.handmodel.builtin.shape import SHAPE_NAMES

__all__ = ["GENERATOR_VERSION", "MODEL_NAME", "SHAPE_NAMES", "build_builtin_hand", "mirror_arrays"]
