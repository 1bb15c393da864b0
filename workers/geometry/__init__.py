"""Cameras, projection with distortion, triangulation and the default 8-camera rig.

Conventions are written once in docs/conventions.md. Names are re-exported lazily so that importing
`workers.geometry.camera` (numpy only) from the API process does not pull in torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "CalibrationError": "camera",
    "Camera": "camera",
    "load_calibration": "camera",
    "save_calibration": "camera",
    "project_points": "projection",
    "project_points_torch": "projection",
    "stack_cameras": "projection",
    "undistort_pixels": "projection",
    "default_rig": "rig",
    "Triangulation": "triangulation",
    "triangulate": "triangulation",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
