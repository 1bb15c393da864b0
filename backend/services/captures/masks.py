"""Binary masks on the wire (run-length encoding) and on disk (8-bit grayscale PNG, 0 or 255).

RLE: row-major runs of alternating values, starting with a run of 0s (possibly of length 0), as in
COCO's uncompressed RLE but row-major. numpy only; no image library in the API process.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from backend.services.errors import InvalidInputError


def decode_rle(counts: list[int], width: int, height: int) -> np.ndarray:
    """(height, width) bool mask from row-major run lengths; InvalidInputError if they do not cover it."""
    runs = np.asarray(counts, dtype=np.int64)
    if runs.ndim != 1 or (runs < 0).any():
        raise InvalidInputError("mask rle: counts must be non-negative integers")
    total = int(runs.sum())
    if total != width * height:
        raise InvalidInputError(f"mask rle covers {total} pixels; the view has {width}x{height} = {width * height}")
    values = np.arange(runs.size) % 2 == 1
    return np.repeat(values, runs).reshape(height, width)


def encode_rle(mask: np.ndarray) -> list[int]:
    flat = np.asarray(mask, dtype=bool).ravel()
    change = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    bounds = np.concatenate(([0], change, [flat.size]))
    runs = np.diff(bounds).tolist()
    if flat.size and flat[0]:
        runs.insert(0, 0)
    return [int(r) for r in runs]


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def encode_png(mask: np.ndarray) -> bytes:
    """8-bit grayscale PNG of a (H, W) bool mask."""
    pixels = np.where(np.asarray(mask, dtype=bool), 255, 0).astype(np.uint8)
    height, width = pixels.shape
    raw = np.concatenate([np.zeros((height, 1), np.uint8), pixels], axis=1).tobytes()  # filter byte 0 per row
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    idat = zlib.compress(raw, 6)
    return b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + _chunk(b"IDAT", idat) + _chunk(b"IEND", b"")


def decode_png(data: bytes) -> np.ndarray:
    """(H, W) bool mask from a PNG written by `encode_png` (8-bit grayscale, filter 0)."""
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        raise InvalidInputError("not a PNG")
    pos, idat, width, height = 8, b"", 0, 0
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            width, height, depth, color = struct.unpack(">IIBB", body[:10])
            if depth != 8 or color != 0:
                raise InvalidInputError("only 8-bit grayscale mask PNGs are read here")
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    rows = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(height, width + 1)
    if rows[:, 0].any():
        raise InvalidInputError("PNG row filters other than 0 are not supported here")
    return rows[:, 1:] > 127
