"""Backgrounds for synthetic views: the green screen of training sequences, and real photographs
(scikit-image's bundled samples, no download) or procedural indoor / outdoor scenes for evaluation.

All functions return (H, W, 3) float32 sRGB in [0, 1] and are deterministic given their rng.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
import skimage.data

# Photographs shipped inside scikit-image's wheel (skimage.data, loaded from disk, never fetched).
PHOTO_NAMES: tuple[str, ...] = ("coffee", "rocket", "motorcycle", "brick", "grass", "gravel", "astronaut",
                                "chelsea")
_LOADERS = {"motorcycle": "stereo_motorcycle"}
PROCEDURAL_NAMES: tuple[str, ...] = ("indoor", "outdoor")
BACKGROUND_NAMES: tuple[str, ...] = tuple(f"photo:{n}" for n in PHOTO_NAMES) + tuple(
    f"procedural:{n}" for n in PROCEDURAL_NAMES)

# A studio green screen under LED light, sRGB.
GREEN_SCREEN_RGB = np.array([0.16, 0.62, 0.25], dtype=np.float32)


def _available_photos() -> tuple[str, ...]:
    return tuple(n for n in PHOTO_NAMES if callable(getattr(skimage.data, _LOADERS.get(n, n), None)))


@lru_cache(maxsize=16)
def load_photo(name: str) -> np.ndarray:
    """A bundled scikit-image photograph as (H, W, 3) float32 sRGB in [0, 1] (greyscale expanded)."""
    loader = getattr(skimage.data, _LOADERS.get(name, name), None)
    if loader is None or name not in PHOTO_NAMES:
        raise ValueError(f"unknown photo {name!r}; choose from {_available_photos()}")
    image = loader()
    if isinstance(image, tuple):  # stereo_motorcycle: (left, right, disparity)
        image = image[0]
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    image = image[..., :3]
    return (image.astype(np.float32) / 255.0) if image.dtype == np.uint8 else image.astype(np.float32)


def _smooth_noise(height: int, width: int, rng: np.random.Generator, cells: int) -> np.ndarray:
    """(H, W) float32 smooth noise in about [-1, 1]: a coarse random grid upsampled bicubically."""
    coarse = rng.uniform(-1, 1, (cells, max(2, round(cells * width / height)))).astype(np.float32)
    return cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)


def green_screen(height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """A lit green screen: linear illumination gradient, vignette, folds (smooth noise), per view.

    Returns:
        (H, W, 3) float32 sRGB in [0, 1].
    """
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    xx, yy = xx / width - 0.5, yy / height - 0.5
    g = rng.normal(0, 0.25, 2)
    gradient = 1.0 + g[0] * xx + g[1] * yy
    vignette = 1.0 - 0.35 * (xx**2 + yy**2)
    folds = 0.04 * _smooth_noise(height, width, rng, 4)
    shade = (gradient * vignette + folds) * rng.uniform(0.8, 1.05)
    tint = GREEN_SCREEN_RGB * rng.uniform(0.92, 1.08, 3).astype(np.float32)
    return np.clip(shade[..., None] * tint[None, None], 0, 1).astype(np.float32)


def _indoor(height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """A room corner: a painted wall, a table edge, shelves and picture frames, soft light falloff."""
    wall = rng.uniform(0.45, 0.85, 3).astype(np.float32)
    image = np.ones((height, width, 3), np.float32) * wall
    image *= (1.0 + 0.08 * _smooth_noise(height, width, rng, 3))[..., None]
    for _ in range(rng.integers(3, 7)):  # furniture, frames, doors: rectangles of other colours
        w, h = rng.integers(width // 8, width // 2), rng.integers(height // 8, height // 2)
        x, y = rng.integers(-w // 2, width), rng.integers(-h // 2, height)
        color = rng.uniform(0.1, 0.9, 3)
        cv2.rectangle(image, (int(x), int(y)), (int(x + w), int(y + h)), color.tolist(), -1)
        cv2.rectangle(image, (int(x), int(y)), (int(x + w), int(y + h)), (color * 0.6).tolist(), 2)
    table_y = int(rng.uniform(0.55, 0.85) * height)
    wood = np.array([0.45, 0.30, 0.18], np.float32) * rng.uniform(0.7, 1.3)
    grain = 0.08 * np.sin(np.linspace(0, rng.uniform(20, 60), width))[None, :, None]
    image[table_y:] = np.clip(wood + grain, 0, 1)
    yy = np.linspace(-0.5, 0.5, height)[:, None]
    xx = np.linspace(-0.5, 0.5, width)[None, :]
    falloff = 1.0 - 0.5 * ((xx - rng.uniform(-0.3, 0.3)) ** 2 + (yy - rng.uniform(-0.3, 0.3)) ** 2)
    return np.clip(image * falloff[..., None].astype(np.float32), 0, 1)


def _outdoor(height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """Sky over vegetation or pavement: a vertical sky gradient, a horizon, textured ground."""
    horizon = int(rng.uniform(0.3, 0.6) * height)
    top, bottom = np.array([0.35, 0.55, 0.9], np.float32), np.array([0.75, 0.85, 0.95], np.float32)
    t = np.linspace(0, 1, max(horizon, 1), dtype=np.float32)[:, None, None]
    sky = top * (1 - t) + bottom * t
    clouds = np.clip(_smooth_noise(max(horizon, 1), width, rng, 3), 0, 1)[..., None]
    image = np.empty((height, width, 3), np.float32)
    image[:horizon] = sky * (1 - 0.6 * clouds) + 0.6 * clouds
    ground = np.array([0.25, 0.4, 0.15] if rng.random() < 0.5 else [0.45, 0.42, 0.38], np.float32)
    texture = 0.25 * _smooth_noise(height - horizon, width, rng, 24) + 0.1 * rng.normal(
        0, 1, (height - horizon, width)).astype(np.float32)
    image[horizon:] = np.clip(ground * (1 + texture[..., None]), 0, 1)
    return image


def evaluation_background(name: str, height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """A background for one evaluation view.

    Args:
        name: "photo:<skimage name>" or "procedural:indoor" / "procedural:outdoor".
        height, width: image size, pixels.
        rng: chooses the crop (photos: each view sees another part, as cameras at different corners
            would) or the procedural layout.
    Returns:
        (H, W, 3) float32 sRGB in [0, 1].
    """
    kind, _, which = name.partition(":")
    if kind == "procedural":
        if which == "indoor":
            return _indoor(height, width, rng)
        if which == "outdoor":
            return _outdoor(height, width, rng)
    elif kind == "photo":
        photo = load_photo(which)
        ph, pw = photo.shape[:2]
        scale = max(height / ph, width / pw) * rng.uniform(1.0, 1.8)
        crop_h, crop_w = min(ph, int(np.ceil(height / scale))), min(pw, int(np.ceil(width / scale)))
        y0 = int(rng.integers(0, ph - crop_h + 1))
        x0 = int(rng.integers(0, pw - crop_w + 1))
        crop = photo[y0:y0 + crop_h, x0:x0 + crop_w]
        if rng.random() < 0.5:
            crop = crop[:, ::-1]
        out = cv2.resize(np.ascontiguousarray(crop), (width, height), interpolation=cv2.INTER_AREA)
        return np.clip(out * rng.uniform(0.8, 1.1), 0, 1).astype(np.float32)
    raise ValueError(f"unknown background {name!r}; choose from {BACKGROUND_NAMES}")


def evaluation_background_names() -> tuple[str, ...]:
    """The evaluation backgrounds available here (photos that this scikit-image version bundles)."""
    return tuple(f"photo:{n}" for n in _available_photos()) + tuple(f"procedural:{n}" for n in PROCEDURAL_NAMES)
