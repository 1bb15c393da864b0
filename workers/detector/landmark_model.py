"""Runs MediaPipe's hand landmark model (hand_landmark_full.tflite) on 224 x 224 crops with ai-edge-litert.

Input: float32 (1, 224, 224, 3) RGB in [0, 1]. Outputs, by name: `Identity` (1, 63) 21 x (x, y, z) in edge-based
crop pixels (x, y in 0..224; z relative depth, same scale); `Identity_1` (1, 1) hand presence; `Identity_2` (1, 1)
handedness (high for a right hand as the model sees it); `Identity_3` (1, 63) world landmarks in metres.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from workers.detector.model_files import HAND_LANDMARK, model_path
from workers.detector.types import DetectorUnavailableError

INPUT_SIZE = 224


@dataclass(frozen=True)
class LandmarkOutput:
    """One crop's model output.

    Attributes:
        keypoints_crop: (21, 2) float64 edge-based crop pixels.
        depth_crop: (21,) float64 relative depth in crop pixels (smaller = nearer the camera).
        presence: hand-presence score in [0, 1].
        right_score: the model's right-hand score in [0, 1] for the crop as shown.
    """

    keypoints_crop: np.ndarray
    depth_crop: np.ndarray
    presence: float
    right_score: float


class LandmarkModel:
    """One interpreter; calls are serialised by a lock (a litert interpreter is not re-entrant).

    One thread by default: measured on the 2-core machine, a crop took 6.4 ms wall with 1 thread and 6.4-9.8 ms with
    2 (load average 5.5), so the second thread only costs CPU that the fit beside it could use.
    """

    def __init__(self, path: Path, num_threads: int = 1) -> None:
        try:
            from ai_edge_litert.interpreter import Interpreter  # deferred: optional runtime, a clear error without it
        except ImportError as exc:
            raise DetectorUnavailableError(
                f"the model runtime ai-edge-litert is not installed ({exc}); install handloop's dependencies") from None
        try:
            self._interpreter = Interpreter(model_path=str(path), num_threads=num_threads)
            self._interpreter.allocate_tensors()
        except (RuntimeError, ValueError) as exc:
            raise DetectorUnavailableError(f"detector model file {path} cannot be loaded ({exc})") from None
        self._input = self._interpreter.get_input_details()[0]["index"]
        outputs = {d["name"]: d["index"] for d in self._interpreter.get_output_details()}
        try:
            self._outputs = tuple(outputs[name] for name in ("Identity", "Identity_1", "Identity_2"))
        except KeyError:
            raise DetectorUnavailableError(f"detector model file {path} lacks the expected outputs") from None
        self._lock = threading.Lock()

    def run(self, crop: np.ndarray) -> LandmarkOutput:
        """(224, 224, 3) float32 RGB crop in [0, 1] -> its landmarks and scores."""
        if crop.shape != (INPUT_SIZE, INPUT_SIZE, 3):
            raise ValueError(f"crop must have shape ({INPUT_SIZE}, {INPUT_SIZE}, 3), got {crop.shape}")
        with self._lock:
            self._interpreter.set_tensor(self._input, crop[None].astype(np.float32, copy=False))
            self._interpreter.invoke()
            landmarks, presence, handedness = (self._interpreter.get_tensor(i).copy() for i in self._outputs)
        landmarks = landmarks.reshape(21, 3).astype(np.float64)
        return LandmarkOutput(landmarks[:, :2], landmarks[:, 2], float(presence.ravel()[0]),
                              float(handedness.ravel()[0]))


def landmark_model() -> LandmarkModel:
    """The process's model, loaded once per verified file (the file is checked on every call: a stat, and a hash
    only when it changed, so files removed or replaced later give DetectorUnavailableError, not a stale model)."""
    return _load(model_path(HAND_LANDMARK))


@lru_cache(maxsize=2)
def _load(path: Path) -> LandmarkModel:
    return LandmarkModel(path)
