"""Square, rotated, optionally mirrored crops of a view, and the exact affine map between crop and image.

Frames: image pixels with (0, 0) at the centre of the top-left pixel (docs/conventions.md); crop coordinates as the
landmark model reports them, continuous and edge-based: (0, 0) is the top-left corner of the crop, (S, S) the
bottom-right, so crop pixel j covers [j, j + 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Crop:
    """A square window on an image.

    Attributes:
        center_px: (2,) x, y of the window's centre, image pixels.
        side_px: side of the window in image pixels (> 0).
        rotation_rad: counter-clockwise rotation of the window in the image (y down), radians; 0 = upright.
        mirrored: True when the crop is flipped left-right (a left hand shown to a right-hand model).
        size: crop side in crop pixels (the model input, 224 for the landmark model).
    """

    center_px: tuple[float, float]
    side_px: float
    rotation_rad: float = 0.0
    mirrored: bool = False
    size: int = 224

    def __post_init__(self) -> None:
        values = (*self.center_px, self.side_px, self.rotation_rad)
        if not all(math.isfinite(v) for v in values) or self.side_px <= 0 or self.size < 1:
            raise ValueError(f"crop needs a finite centre and rotation and a positive side, got {self}")

    def crop_to_image(self) -> np.ndarray:
        """(2, 3) affine: edge-based crop coordinates (u, v, 1) -> image pixels."""
        scale = self.side_px / self.size
        cos, sin = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        # The crop's x axis points (cos, -sin) in the image and its y axis (down) points (sin, cos): a window turned
        # counter-clockwise on screen. Mirroring flips the crop's x axis before the rotation.
        ex = np.array([cos, -sin]) * scale * (-1.0 if self.mirrored else 1.0)
        ey = np.array([sin, cos]) * scale
        origin = np.asarray(self.center_px, dtype=np.float64) - (ex + ey) * self.size / 2
        return np.stack([ex, ey, origin], axis=1)

    def image_to_crop(self) -> np.ndarray:
        """(2, 3) affine: image pixels -> edge-based crop coordinates (the exact inverse of `crop_to_image`)."""
        return cv2.invertAffineTransform(self.crop_to_image())

    def to_image(self, points_crop: np.ndarray) -> np.ndarray:
        """(..., 2) edge-based crop coordinates -> (..., 2) image pixels."""
        return _apply(self.crop_to_image(), points_crop)

    def to_crop(self, points_px: np.ndarray) -> np.ndarray:
        """(..., 2) image pixels -> (..., 2) edge-based crop coordinates."""
        return _apply(self.image_to_crop(), points_px)

    def extract(self, image: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 image -> (size, size, 3) float32 crop in [0, 1] (zeros outside the image)."""
        A = self.crop_to_image()
        # warpAffine samples crop pixel centres (j, i) at integer coordinates; edge-based they are (j + 0.5, i + 0.5).
        M = A.copy()
        M[:, 2] += 0.5 * (A[:, 0] + A[:, 1])
        out = cv2.warpAffine(image, M, (self.size, self.size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return out.astype(np.float32) / 255.0

    def bounds_px(self) -> np.ndarray:
        """(4,) x, y, width, height of the window's axis-aligned bounds in image pixels."""
        corners = self.to_image(np.array([[0, 0], [self.size, 0], [0, self.size], [self.size, self.size]], float))
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        return np.array([lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1]])

    def turned(self, rotation_rad: float) -> Crop:
        return Crop(self.center_px, self.side_px, rotation_rad, self.mirrored, self.size)


def _apply(affine: np.ndarray, points: np.ndarray) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    return points @ affine[:, :2].T + affine[:, 2]


def upright_rotation(wrist_px: np.ndarray, middle_mcp_px: np.ndarray) -> float:
    """The crop rotation (radians) that shows the wrist -> middle-finger-MCP direction pointing up in the crop."""
    dx, dy = np.asarray(middle_mcp_px, float) - np.asarray(wrist_px, float)
    return math.atan2(-dx, -dy)


def crop_from_mask(mask: np.ndarray, scale: float, min_side_px: float = 16.0) -> tuple[float, float, float] | None:
    """(H, W) bool mask -> (x, y, side) of a square around its largest blob, `scale` times its longer side.

    None when the mask is empty. The largest connected component keeps stray chroma-key specks out of the box.
    """
    windows = mask_windows(mask, scale, min_side_px, max_count=1)
    return windows[0] if windows else None


def mask_windows(mask: np.ndarray, scale: float, min_side_px: float = 16.0, *, min_area_fraction: float = 0.2,
                 max_count: int = 4) -> list[tuple[float, float, float]]:
    """(H, W) bool mask -> (x, y, side) squares around its blobs, largest first, `scale` times each one's longer side.

    Only blobs of at least `min_area_fraction` of the largest one's area count (chroma-key specks do not; a second
    hand with its forearm does); at most `max_count`.
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        return []
    count, _, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if count < 2:
        return []
    areas = stats[1:, cv2.CC_STAT_AREA]
    order = 1 + np.argsort(-areas, kind="stable")
    out = []
    for blob in order[:max_count]:
        if stats[blob, cv2.CC_STAT_AREA] < min_area_fraction * areas.max():
            break
        x, y, w, h = (float(v) for v in stats[blob, :4])
        side = max(w, h, min_side_px) * scale
        out.append((x + (w - 1) / 2, y + (h - 1) / 2, side))
    return out


def crop_from_keypoints(keypoints_px: np.ndarray, scale: float) -> tuple[float, float, float]:
    """(21, 2) keypoints -> (x, y, side) of a square around them, `scale` times the longer side of their box."""
    lo, hi = keypoints_px.min(axis=0), keypoints_px.max(axis=0)
    center = (lo + hi) / 2
    return float(center[0]), float(center[1]), float(max(hi - lo) * scale)
