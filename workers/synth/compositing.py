"""From rendered views to camera-like images: soft edges over the background, green spill on the
green screen, sensor noise; and the chroma key the real pipeline would run on green-screen frames.

Images are float32 sRGB in [0, 1] until `to_uint8`.
"""

from __future__ import annotations

import cv2
import numpy as np

GAMMA = 2.2
# Colour multiplier of green-screen spill at full strength (RGB).
SPILL_TINT = np.array([0.6, 1.45, 0.7], dtype=np.float32)


def srgb_to_linear(rgb: np.ndarray) -> np.ndarray:
    """sRGB in [0, 1] -> linear (a 2.2 power curve; close enough for synthetic albedo)."""
    return np.power(np.clip(rgb, 0, 1), GAMMA).astype(np.float32)


def linear_to_srgb(rgb: np.ndarray) -> np.ndarray:
    """linear -> sRGB in [0, 1], clipped."""
    return np.power(np.clip(rgb, 0, 1), 1.0 / GAMMA).astype(np.float32)


def hex_to_srgb(hex_color: str) -> np.ndarray:
    """'#a07e56' or 'a07e56' -> (3,) float32 sRGB in [0, 1]."""
    h = hex_color.lstrip("#")
    return np.array([int(h[i:i + 2], 16) for i in (0, 2, 4)], np.float32) / 255.0


def apply_green_spill(foreground: np.ndarray, mask: np.ndarray, strength: float,
                      width_px: float = 1.5) -> np.ndarray:
    """Tint the foreground's edge pixels with light bounced off the green screen (in place).

    Args:
        foreground: (H, W, 3) float32 sRGB of the rendered subject.
        mask: (H, W) bool foreground.
        strength: tint at the very edge, 0..1; it decays as exp(-(d - 1) / width_px) inwards, where d is
            the distance in pixels to the nearest background pixel.
        width_px: decay distance in pixels.
    Returns:
        `foreground`, tinted.
    """
    # Distance of each foreground pixel to the nearest background pixel (OpenCV, L2, 5x5 mask).
    dist = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    band = mask & (dist < 1.0 + 4.0 * width_px)  # beyond this the tint is < 2 %: skip the pixels
    weight = (strength * np.exp(-(dist[band] - 1.0) / width_px)).astype(np.float32)[:, None]
    # Bounced screen light: green grows, red and blue fade, in proportion to the pixel's own colour.
    foreground[band] = foreground[band] * (1.0 + weight * (SPILL_TINT[None] - 1.0))
    return np.clip(foreground, 0.0, 1.0, out=foreground)


def camera_image(color_linear: np.ndarray, mask: np.ndarray, background: np.ndarray, *, spill: float,
                 noise: np.ndarray | None, spill_width_px: float = 1.5, edge_sigma_px: float = 0.55) -> np.ndarray:
    """Turn a rendered view into a camera-like 8-bit image.

    Steps: linear -> sRGB on the subject's pixels; green spill at its edge (`spill` > 0); alpha blend
    over the background with a slightly blurred mask (anti-aliasing stand-in; the edge colour is
    spread outwards first so the blend does not darken); add sensor noise; round to uint8.

    Args:
        color_linear: (H, W, 3) float32 linear RGB of the rendered subject (0 elsewhere).
        mask: (H, W) bool subject pixels.
        background: (H, W, 3) float32 sRGB in [0, 1].
        spill: green spill strength at the edge (0: none).
        spill_width_px: decay distance of the spill, pixels.
        noise: (H, W, 3) float32 additive noise in [0, 1] units, or None.
        edge_sigma_px: blur of the mask's edge, pixels.
    Returns:
        (H, W, 3) uint8 RGB.
    """
    fg = np.zeros_like(background)
    fg[mask] = linear_to_srgb(color_linear[mask])
    if spill > 0:
        apply_green_spill(fg, mask, spill, spill_width_px)
    alpha = cv2.GaussianBlur(mask.astype(np.float32), (3, 3), edge_sigma_px)
    ring = (alpha > 0) & ~mask
    fg[ring] = cv2.dilate(fg, np.ones((3, 3), np.uint8))[ring]
    out = cv2.blendLinear(fg, background, alpha, 1.0 - alpha)  # OpenCV: one pass, no temporaries
    if noise is not None:
        out += noise
    # Saturating float -> uint8 in one OpenCV call (|x| is harmless: values are >= 0 up to noise).
    return cv2.convertScaleAbs(out, alpha=255.0, beta=0.5)


class NoiseBank:
    """Gaussian sensor noise without drawing H x W x 3 normals per view: a few seeded noise fields per
    image size, and per view a random field and a random offset into it (the noise of neighbouring
    views is then shifted copies of a few fields, which nothing downstream can tell apart)."""

    def __init__(self, sigma: float, seed: int = 0, fields: int = 3, margin_px: int = 32) -> None:
        self.sigma = float(sigma)
        self.seed = seed
        self.fields = fields
        self.margin = margin_px
        self._banks: dict[tuple[int, int], list[np.ndarray]] = {}

    def sample(self, height: int, width: int, rng: np.random.Generator) -> np.ndarray:
        """(H, W, 3) float32 noise, standard deviation `sigma`, chosen by `rng`."""
        key = (height, width)
        if key not in self._banks:
            gen = np.random.default_rng([self.seed, height, width])
            shape = (height + self.margin, width + self.margin, 3)
            self._banks[key] = [gen.standard_normal(shape, dtype=np.float32) * np.float32(self.sigma)
                                for _ in range(self.fields)]
        field = self._banks[key][int(rng.integers(self.fields))]
        dy, dx = (int(v) for v in rng.integers(0, self.margin + 1, 2))
        return field[dy:dy + height, dx:dx + width]


def chroma_key(rgb: np.ndarray, *, hue_range: tuple[int, int] = (35, 88), min_saturation: int = 70,
               min_value: int = 35, min_green_excess: int = 24, min_area_px: int = 4) -> np.ndarray:
    """Foreground mask of a green-screen image, as a capture pipeline computes it.

    Pixels whose HSV colour is green enough and whose green exceeds red and blue by `min_green_excess`
    levels are screen; the rest is foreground, minus connected
    specks smaller than `min_area_px` (no morphological opening: at working resolution a finger can be
    two pixels wide).

    Args:
        rgb: (H, W, 3) uint8 RGB.
        hue_range: OpenCV hue (0..180) range of the screen.
        min_saturation, min_value: 0..255 thresholds of the screen.
        min_green_excess: G - max(R, B) needed for screen, 0..255.
        min_area_px: smaller foreground components are dropped.
    Returns:
        (H, W) bool foreground (hand, forearm, sleeve, held object).
    """
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    screen = cv2.inRange(hsv, (hue_range[0], min_saturation, min_value), (hue_range[1], 255, 255))
    # Colour-difference condition as in broadcast keyers: green must exceed red and blue by a margin,
    # so dark pixels (where a few levels of difference already mean high HSV saturation) stay foreground.
    r, g, b = (rgb[..., i].astype(np.int16) for i in range(3))
    screen &= ((g - np.maximum(r, b)) >= min_green_excess).astype(np.uint8) * 255
    foreground = (255 - screen).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(foreground, connectivity=8)
    small = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] < min_area_px)
    mask = foreground > 0
    if count > 1 and len(small):
        mask &= ~np.isin(labels, small)
    return mask
