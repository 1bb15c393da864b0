"""MANO-compatible hand models: the official MANO loader, the built-in procedural stand-in, the parameters
(`HandParams`), one forward pass with a torch face (`HandLayer`) and a numpy face (`posed_mesh`), joint
limits and the pose sampler. See docs/hand-model.md.

Names are re-exported lazily so importing the package does not pull in torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "HandModelArrays": "arrays",
    "HandModelError": "arrays",
    "HandLayer": "layer",
    "HandOutput": "layer",
    "HandParams": "params",
    "HandMesh": "posed",
    "posed_mesh": "posed",
    "load_hand_model": "loading",
    "STAND_IN_NOTICE": "loading",
    "load_mano": "mano_loader",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
