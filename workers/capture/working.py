"""The working resolution (capture format v2's `working_width_px`, issue 18): what the networks, the detector
and the UI read instead of the full-resolution originals, and the way back to full-resolution pixels.

Conventions (docs/capture-format.md "Working resolution"):
- A camera wider than the working width W is read at W px wide, its height h = round(H W / width) (the
  aspect ratio kept); its intrinsics are `Camera.scaled(W)`, each axis scaled as the resized image is
  (pixel-centre convention: u' = sx (u + 0.5) - 0.5, v' = sy (v + 0.5) - 0.5, sx = W / width, sy = h / H).
  A camera no wider than W is read as stored.
- Pixels leave the working resolution only through `to_full_px`: clicks, keypoints, boxes and masks are
  stored and shown in full-resolution pixels.
- A working copy is derived from the original: images with area averaging (after libjpeg's reduced-scale
  decode where that stays at least W wide and its factor divides both sides), masks with area averaging
  then a 0.5 cut. Copies are kept beside the originals (storage key `derived-v2/w<W>/<original key
  stem>.jpg|png`), never as the only copy.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from workers.geometry.camera import Camera

# The version in the prefix changes when copies made by earlier code are wrong: v2 (2026-12-03) because the
# reduced decode used a factor not dividing both sides and Camera.scaled one factor for both axes; those copies
# are newer than their originals, so only a new prefix derives them again.
DERIVED_PREFIX = "derived-v2"
JPEG_QUALITY = 92


def working_size(full_width: int, full_height: int, width: int) -> tuple[int, int]:
    """(width, height) of a working copy of a full_width x full_height image: the aspect ratio kept with the
    rounding of `Camera.scaled` (so a copy always has its scaled camera's size)."""
    if width < 1 or full_width < 1 or full_height < 1:
        raise ValueError(f"sizes must be positive, got {full_width}x{full_height} -> width {width}")
    return width, max(1, round(full_height * width / full_width))


def working_camera(camera: Camera, width: int | None) -> Camera:
    """The camera as the networks see it: `camera.scaled(width)` when it is wider than `width`, else itself."""
    if width is None or camera.width <= width:
        return camera
    return camera.scaled(width)


def working_cameras(cameras: Sequence[Camera], width: int | None) -> tuple[Camera, ...]:
    """`working_camera` of each camera, same order."""
    return tuple(working_camera(c, width) for c in cameras)


def is_reduced(cameras: Sequence[Camera], width: int | None) -> bool:
    """Whether any camera is read at a lower resolution than stored."""
    return width is not None and any(c.width > width for c in cameras)


def _scale(working: Camera, full: Camera) -> np.ndarray:
    """(2,) factors (sx, sy) full -> working pixels: each axis its own, as the resized image has them."""
    return np.array([working.width / full.width, working.height / full.height])


def to_full_px(px: np.ndarray, working: Camera, full: Camera) -> np.ndarray:
    """Pixels of the working copy -> pixels of the full-resolution image (u = (u' + 0.5) / sx - 0.5,
    v = (v' + 0.5) / sy - 0.5, sx = w / W and sy = h / H).

    Args:
        px: (..., 2) float pixels (x, y) in `working`'s image; NaN stays NaN.
        working, full: the same camera at the working and at the full resolution (working = full.scaled(w)).
    Returns:
        (..., 2) float64 pixels in `full`'s image; the exact inverse of `Camera.scaled`'s intrinsics, so a
        point projected with `working` maps onto its projection with `full`.
    """
    return (np.asarray(px, np.float64) + 0.5) / _scale(working, full) - 0.5


def to_full_length_px(length_px: np.ndarray, working: Camera, full: Camera) -> np.ndarray:
    """(..., 2) lengths along x and y (a box's width and height) in working pixels -> full-resolution pixels."""
    return np.asarray(length_px, np.float64) / _scale(working, full)


def mask_to_working(mask: np.ndarray, working: Camera) -> np.ndarray:
    """(H, W) bool/float full-resolution mask -> (h, w) bool at `working`'s size (area average >= 0.5)."""
    mask = np.asarray(mask)
    if mask.shape == (working.height, working.width):
        return mask.astype(bool) if mask.dtype == bool else mask >= 0.5
    area = cv2.resize(mask.astype(np.float32), (working.width, working.height), interpolation=cv2.INTER_AREA)
    return area >= 0.5


def probabilities_to_full(probabilities: np.ndarray, full: Camera) -> np.ndarray:
    """(h, w) float map at a working size -> (H, W) float32 at `full`'s size (bilinear; the pixel-centre
    convention of `Camera.scaled` is cv2.resize's own)."""
    probabilities = np.asarray(probabilities, np.float32)
    if probabilities.shape == (full.height, full.width):
        return probabilities
    return cv2.resize(probabilities, (full.width, full.height), interpolation=cv2.INTER_LINEAR)


def derived_key(original_key: str, width: int, suffix: str = ".jpg") -> str:
    """The storage key of an original's working copy (`derived-v2/w<width>/<stem><suffix>`)."""
    stem = original_key.rsplit(".", 1)[0]
    return f"{DERIVED_PREFIX}/w{width}/{stem}{suffix}"


def _reduced_flag(data: bytes, full_size: tuple[int, int], width: int, colour: bool) -> int:
    """libjpeg's DCT scaling (1/2, 1/4, 1/8) as far as the decoded image stays at least `width` wide: a
    2048 px JPEG decoded at 1/2 for a 640 px copy costs ~2.7x less than in full.

    Only for JPEG data and a factor f dividing both sides: libjpeg gives ceil(W / f) x ceil(H / f) pixels, a
    partial last one included, which the resize would stretch onto the working size. PNG gets the plain
    flag: OpenCV would decode it fully and subsample with INTER_LINEAR_EXACT (aliasing).
    """
    plain = cv2.IMREAD_COLOR if colour else cv2.IMREAD_GRAYSCALE
    if data[:2] != b"\xff\xd8":
        return plain
    full_width, full_height = full_size
    steps = ((8, cv2.IMREAD_REDUCED_COLOR_8, cv2.IMREAD_REDUCED_GRAYSCALE_8),
             (4, cv2.IMREAD_REDUCED_COLOR_4, cv2.IMREAD_REDUCED_GRAYSCALE_4),
             (2, cv2.IMREAD_REDUCED_COLOR_2, cv2.IMREAD_REDUCED_GRAYSCALE_2))
    for factor, reduced_colour, reduced_grey in steps:
        if full_width % factor == 0 and full_height % factor == 0 and full_width // factor >= width:
            return reduced_colour if colour else reduced_grey
    return plain


def working_image(data: bytes, full_size: tuple[int, int], size: tuple[int, int], what: str) -> np.ndarray:
    """An encoded image (JPEG/PNG bytes of a full_size = (width, height) original) -> (h, w, 3) uint8 BGR at
    `size` (width, height). ValueError naming `what` when it cannot be decoded."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), _reduced_flag(data, full_size, size[0], colour=True))
    if image is None:
        raise ValueError(f"image {what!r} cannot be decoded")
    if (image.shape[1], image.shape[0]) == size:
        return image
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def working_jpeg(data: bytes, full_size: tuple[int, int], size: tuple[int, int], what: str) -> bytes:
    """`working_image` encoded as a JPEG (quality JPEG_QUALITY): the working copy's bytes."""
    ok, encoded = cv2.imencode(".jpg", working_image(data, full_size, size, what),
                               [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError(f"image {what!r}: its working copy could not be encoded")
    return encoded.tobytes()


def working_mask_png(data: bytes, size: tuple[int, int], what: str) -> bytes:
    """An encoded 8-bit mask (>= 128 = inside) -> its working copy as a PNG (0 / 255) of `size`."""
    mask = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    if mask is None:
        raise ValueError(f"mask {what!r} cannot be decoded")
    area = cv2.resize((mask >= 128).astype(np.float32), size, interpolation=cv2.INTER_AREA)
    ok, encoded = cv2.imencode(".png", (area >= 0.5).astype(np.uint8) * 255)
    if not ok:
        raise ValueError(f"mask {what!r}: its working copy could not be encoded")
    return encoded.tobytes()


def load_working_images(image_paths: dict[str, Path], full: Sequence[Camera], working: Sequence[Camera]
                        ) -> dict[str, np.ndarray]:
    """A frame's images read straight at the working size, without copies (a capture on disk: the calibration
    check's detector). Returns camera name -> (h, w, 3) uint8 RGB; ValueError naming an unreadable file."""
    out = {}
    for cam, small in zip(full, working, strict=True):
        path = Path(image_paths[cam.name])
        bgr = working_image(path.read_bytes(), (cam.width, cam.height), (small.width, small.height), str(path))
        out[cam.name] = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    return out
