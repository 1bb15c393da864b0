"""MediaPipe's palm detector (palm_detection_full.tflite): where a hand is when no mask says so.

Input float32 (1, 192, 192, 3) RGB in [0, 1] of a square window (the letterboxed image by default). Outputs:
`Identity` (1, 2016, 18) box regressions (centre offset x, y, width, height, then 7 palm keypoints x, y, in input
pixels relative to the anchor) and `Identity_1` (1, 2016, 1) score logits. The 2016 anchors are SSD anchors of fixed
size on a 24 x 24 grid (stride 8, 2 per cell) and a 12 x 12 grid (stride 16, 6 per cell), centres at cell centres;
keypoint 0 is the wrist and 2 the middle finger's MCP. The hand crop follows MediaPipe's rule: the palm box turned so
wrist -> middle MCP points up, shifted half its height towards the fingers, 2.6 times its longer side.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from workers.detector.crops import Crop, upright_rotation
from workers.detector.model_files import PALM_DETECTION, model_path
from workers.detector.types import DetectorUnavailableError

INPUT_SIZE = 192
MIN_SCORE = 0.5
NMS_IOU = 0.3
CROP_SCALE = 2.6
CROP_SHIFT_Y = -0.5


def palm_anchors() -> np.ndarray:
    """(2016, 2) anchor centres in [0, 1] of the 192 x 192 input, in the model's output order."""
    rows = []
    for grid, per_cell in ((24, 2), (12, 6)):
        ys, xs = np.meshgrid((np.arange(grid) + 0.5) / grid, (np.arange(grid) + 0.5) / grid, indexing="ij")
        cells = np.stack([xs.ravel(), ys.ravel()], axis=1)
        rows.append(np.repeat(cells, per_cell, axis=0))
    return np.concatenate(rows)


@dataclass(frozen=True)
class PalmDetection:
    """One palm: score in [0, 1], box (4,) x, y, w, h and keypoints (7, 2) in image pixels, and its hand crop."""

    score: float
    box_px: np.ndarray
    keypoints_px: np.ndarray
    crop: Crop


class PalmDetector:
    def __init__(self, path: Path, num_threads: int = 1) -> None:
        try:
            from ai_edge_litert.interpreter import Interpreter  # deferred: optional runtime, a clear error without it
        except ImportError as exc:
            raise DetectorUnavailableError(f"the model runtime ai-edge-litert is not installed ({exc})") from None
        try:
            self._interpreter = Interpreter(model_path=str(path), num_threads=num_threads)
            self._interpreter.allocate_tensors()
        except (RuntimeError, ValueError) as exc:
            raise DetectorUnavailableError(f"detector model file {path} cannot be loaded ({exc})") from None
        self._input = self._interpreter.get_input_details()[0]["index"]
        outputs = {d["name"]: d["index"] for d in self._interpreter.get_output_details()}
        self._boxes, self._scores = outputs["Identity"], outputs["Identity_1"]
        self._anchors = palm_anchors()
        self._lock = threading.Lock()

    def detect(self, image: np.ndarray, window: Crop | None = None, max_palms: int = 2) -> list[PalmDetection]:
        """Palms in `image` (H, W, 3) uint8 RGB above MIN_SCORE, best first, after non-maximum suppression.

        Args:
            window: the part of the image to look in (the model sees it at 192 x 192, so a window around a mask finds
                smaller hands than the whole image does); default the whole image, letterboxed.
        """
        if window is None:
            height, width = image.shape[:2]
            window = Crop(((width - 1) / 2, (height - 1) / 2), float(max(height, width)))
        window = Crop(window.center_px, window.side_px, window.rotation_rad, window.mirrored, INPUT_SIZE)
        with self._lock:
            self._interpreter.set_tensor(self._input, window.extract(image)[None])
            self._interpreter.invoke()
            raw = self._interpreter.get_tensor(self._boxes)[0].astype(np.float64)
            logits = self._interpreter.get_tensor(self._scores)[0, :, 0].astype(np.float64)
        scores = 1.0 / (1.0 + np.exp(-np.clip(logits, -100, 100)))
        keep = np.flatnonzero(scores >= MIN_SCORE)
        if keep.size == 0:
            return []
        anchors = self._anchors[keep] * INPUT_SIZE  # edge-based input pixels
        centers = raw[keep, 0:2] + anchors
        sizes = raw[keep, 2:4]
        points = raw[keep, 4:18].reshape(-1, 7, 2) + anchors[:, None]
        boxes = np.concatenate([centers - sizes / 2, centers + sizes / 2], axis=1)
        scale = window.side_px / INPUT_SIZE
        palms = []
        for i in _nms(boxes, scores[keep], NMS_IOU)[:max_palms]:
            center, size = window.to_image(centers[i]), sizes[i] * scale
            kps = window.to_image(points[i])
            rotation = upright_rotation(kps[0], kps[2])
            # Shift towards the fingers in the turned frame: the crop's -y axis is (-sin, -cos) in the image.
            shift = CROP_SHIFT_Y * size[1] * np.array([math.sin(rotation), math.cos(rotation)])
            crop = Crop((float(center[0] + shift[0]), float(center[1] + shift[1])), float(max(size) * CROP_SCALE),
                        rotation)
            palms.append(PalmDetection(float(scores[keep][i]), np.array([*(center - size / 2), *size]), kps, crop))
        return palms


def _nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> list[int]:
    """Indices of boxes (N, 4) x0, y0, x1, y1 kept by greedy non-maximum suppression, best score first."""
    order = list(np.argsort(-scores))
    kept: list[int] = []
    while order:
        i = order.pop(0)
        kept.append(int(i))
        if not order:
            break
        rest = np.asarray(order)
        x0 = np.maximum(boxes[i, 0], boxes[rest, 0])
        y0 = np.maximum(boxes[i, 1], boxes[rest, 1])
        x1 = np.minimum(boxes[i, 2], boxes[rest, 2])
        y1 = np.minimum(boxes[i, 3], boxes[rest, 3])
        inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
        area = lambda b: (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1])  # noqa: E731
        overlap = inter / (area(boxes[i]) + area(boxes[rest]) - inter + 1e-12)
        order = [int(j) for j, o in zip(rest, overlap, strict=True) if o <= iou]
    return kept


def palm_detector() -> PalmDetector:
    """The process's model, loaded once per verified file (the file is checked on every call: a stat, and a hash
    only when it changed, so files removed or replaced later give DetectorUnavailableError, not a stale model)."""
    return _load(model_path(PALM_DETECTION))


@lru_cache(maxsize=2)
def _load(path: Path) -> PalmDetector:
    return PalmDetector(path)
