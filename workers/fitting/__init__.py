"""Fitting the hand model to multi-view clicks, 3D keypoints and silhouettes (docs/fitting.md).

`from workers.fitting import FittingEngine, FitConfig, FrameObservations` works; the names load lazily so
that importing a light submodule (e.g. `workers.fitting.inputs`) does not import torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "FittingEngine": "workers.fitting.engine",
    "FitConfig": "workers.fitting.config",
    "LossWeights": "workers.fitting.config",
    "FrameObservations": "workers.fitting.inputs",
    "FitInputError": "workers.fitting.inputs",
    "FitResult": "workers.fitting.result",
    "FitDiagnostics": "workers.fitting.result",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
