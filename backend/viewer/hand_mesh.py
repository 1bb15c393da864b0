"""Which hand model made a fit, and its arrays in the API process (torch-free).

The mesh itself is the hand model's numpy face, `workers.handmodel.posed.posed_mesh`; parameters are
`workers.handmodel.params.HandParams` (theta (61,), docs/conventions.md).
"""

from __future__ import annotations

import logging
from pathlib import Path

from workers.handmodel.arrays import HandModelArrays
from workers.handmodel.loading import load_hand_model

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
