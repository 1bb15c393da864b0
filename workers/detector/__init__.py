"""Pretrained 2D hand keypoints (MediaPipe's hand landmark model) and their multi-view lifting.

Part of the compute core: no database, no web. The public entry points:
- `detect_frame(images, cameras, masks=None, *, handedness="right") -> LiftedKeypoints`: the hand of that side,
  the same in every view, where several hands are in view (docs/detector.md, "Several hands in view")
- `detector_status() -> str | None`: None when the model files are present and verified, else why not.
"""

from __future__ import annotations

from typing import Any

from workers.detector.types import (
    DetectorInputError,
    DetectorUnavailableError,
    Handedness,
    LiftedKeypoints,
    ViewKeypoints,
)

__all__ = [
    "DetectorInputError",
    "DetectorUnavailableError",
    "Handedness",
    "LiftedKeypoints",
    "ViewKeypoints",
    "detect_frame",
    "detector_status",
]


def __getattr__(name: str) -> Any:
    # deferred: the pipeline (torch, the model runtime ai-edge-litert) loads only when a detection or the detector's
    # status is asked for, not at the API's start-up
    if name in ("detect_frame", "detector_status"):
        from workers.detector import pipeline

        return getattr(pipeline, name)
    raise AttributeError(f"module 'workers.detector' has no attribute {name!r}")
