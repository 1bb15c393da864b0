"""Chroma keying with per-capture settings (key colour and hue tolerance), and its preview image.

The screen is what is close to the key colour's hue, saturated and bright enough, and whose key channel
(the key colour's strongest of R, G, B) exceeds the other two by a margin (the colour-difference test of
broadcast keyers, which keeps dark pixels foreground). Everything else is foreground, minus specks.
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np

HEX_COLOR = re.compile(r"^#[0-9a-fA-F]{6}$")


@dataclass(frozen=True)
class ChromaKey:
    """Keyer settings stored in sequence.json's `chroma_key`.

    Attributes:
        color: the screen's colour, sRGB hex "#rrggbb".
        tolerance_deg: hue distance from the key colour still counted as screen, degrees (0..90).
        min_saturation, min_value: HSV thresholds of the screen, 0..255.
        min_excess: key channel minus the larger other channel needed for screen, 0..255.
        min_area_px: foreground components smaller than this are dropped.
    """

    color: str = "#00b140"
    tolerance_deg: float = 30.0
    min_saturation: int = 70
    min_value: int = 35
    min_excess: int = 24
    min_area_px: int = 16

    def __post_init__(self) -> None:
        if not isinstance(self.color, str) or not HEX_COLOR.match(self.color):
            raise ValueError(f"chroma key: field 'color' must be a hex colour like '#00b140', got {self.color!r}")
        if not (isinstance(self.tolerance_deg, int | float) and np.isfinite(self.tolerance_deg)
                and 0 < self.tolerance_deg <= 90):
            raise ValueError("chroma key: field 'tolerance_deg' must be in (0, 90] degrees, got "
                             f"{self.tolerance_deg!r}")
        for key in ("min_saturation", "min_value", "min_excess"):
            value = getattr(self, key)
            if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 255:
                raise ValueError(f"chroma key: field {key!r} must be an integer in 0..255, got {value!r}")
        if not isinstance(self.min_area_px, int) or self.min_area_px < 0:
            raise ValueError(f"chroma key: field 'min_area_px' must be a non-negative integer, got "
                             f"{self.min_area_px!r}")

    @property
    def rgb(self) -> tuple[int, int, int]:
        return tuple(int(self.color[i:i + 2], 16) for i in (1, 3, 5))  # type: ignore[return-value]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Any) -> ChromaKey:
        if not isinstance(data, dict):
            raise ValueError(f"chroma key: expected an object, got {type(data).__name__}")
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"chroma key: unknown field(s) {sorted(unknown)}")
        return cls(**data)


def key_mask(rgb: np.ndarray, key: ChromaKey) -> np.ndarray:
    """(H, W) bool foreground of an (H, W, 3) uint8 RGB image keyed with `key`."""
    swatch = np.array([[key.rgb]], dtype=np.uint8)
    hue = int(cv2.cvtColor(swatch, cv2.COLOR_RGB2HSV)[0, 0, 0])  # OpenCV hue: degrees / 2
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    distance = np.abs(hsv[..., 0].astype(np.int16) - hue)
    distance = np.minimum(distance, 180 - distance)  # hue is circular
    screen = (distance <= key.tolerance_deg / 2) & (hsv[..., 1] >= key.min_saturation) & (hsv[..., 2] >= key.min_value)
    channel = int(np.argmax(key.rgb))
    others = [c for c in range(3) if c != channel]
    excess = rgb[..., channel].astype(np.int16) - np.maximum(rgb[..., others[0]], rgb[..., others[1]])
    screen &= excess >= key.min_excess
    foreground = (~screen).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(foreground, connectivity=8)
    small = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] < key.min_area_px)
    small = small[small > 0]
    mask = foreground > 0
    if count > 1 and len(small):
        mask &= ~np.isin(labels, small)
    return mask


def preview(images: list[np.ndarray], masks: list[np.ndarray], tile_width: int = 320) -> np.ndarray:
    """A grid of views with the screen shown dimmed and magenta-tinted: (H, W, 3) uint8 RGB."""
    tiles = []
    for rgb, mask in zip(images, masks, strict=True):
        h, w = rgb.shape[:2]
        size = (tile_width, max(1, round(h * tile_width / w)))
        small = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
        keep = cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST).astype(bool)
        tinted = (0.35 * small + 0.65 * np.array([255, 0, 255])).astype(np.uint8)
        tiles.append(np.where(keep[..., None], small, tinted))
    cols = min(4, len(tiles))
    rows = -(-len(tiles) // cols)
    height = max(t.shape[0] for t in tiles)
    grid = np.zeros((rows * height, cols * tile_width, 3), np.uint8)
    for i, tile in enumerate(tiles):
        r, c = divmod(i, cols)
        grid[r * height:r * height + tile.shape[0], c * tile_width:(c + 1) * tile_width] = tile
    return grid
