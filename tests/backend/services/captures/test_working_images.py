"""backend/services/captures/working_images.py: working copies in storage follow their originals."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from backend.services.captures.storage import LocalDiskStorage
from backend.services.captures.working_images import ensure_working_copy
from backend.services.errors import NotFoundError


def _png(value: int) -> bytes:
    ok, data = cv2.imencode(".png", np.full((96, 128), value, np.uint8))
    assert ok
    return data.tobytes()


def _mtime_ns(storage: LocalDiskStorage, key: str) -> int:
    return storage.local_path(key).stat().st_mtime_ns


@pytest.mark.parametrize("mask", [False, True])
def test_a_copy_is_derived_again_when_its_original_is_rewritten(tmp_path, mask) -> None:
    """An original rewritten under the same key (storage outliving a recreated database) gets a fresh copy,
    whatever the clocks' resolution (the copy's time is set one second before the rewritten original's)."""
    storage = LocalDiskStorage(tmp_path)
    storage.put_bytes("images/p1/cam0/000000.png", _png(0))
    key = ensure_working_copy(storage, "images/p1/cam0/000000.png", 128, 96, 64, mask=mask)
    assert key == ("derived-v2/w64/images/p1/cam0/000000" + (".png" if mask else ".jpg"))
    first = cv2.imdecode(np.frombuffer(storage.get_bytes(key), np.uint8), cv2.IMREAD_GRAYSCALE)
    assert first.shape == (48, 64) and first.max() <= 2
    storage.put_bytes("images/p1/cam0/000000.png", _png(255))
    earlier = _mtime_ns(storage, "images/p1/cam0/000000.png") - 1_000_000_000
    os.utime(storage.local_path(key), ns=(earlier, earlier))
    assert ensure_working_copy(storage, "images/p1/cam0/000000.png", 128, 96, 64, mask=mask) == key
    second = cv2.imdecode(np.frombuffer(storage.get_bytes(key), np.uint8), cv2.IMREAD_GRAYSCALE)
    assert second.min() >= 253
    untouched = _mtime_ns(storage, key)  # a fresh copy is kept, not derived again
    assert ensure_working_copy(storage, "images/p1/cam0/000000.png", 128, 96, 64, mask=mask) == key
    assert _mtime_ns(storage, key) == untouched


def test_a_missing_or_undecodable_original_is_named(tmp_path) -> None:
    storage = LocalDiskStorage(tmp_path)
    with pytest.raises(NotFoundError, match=r"'images/none\.png' is missing"):
        ensure_working_copy(storage, "images/none.png", 128, 96, 64)
    storage.put_bytes("images/bad.png", b"not an image")
    with pytest.raises(NotFoundError, match=r"'images/bad\.png in storage' cannot be decoded"):
        ensure_working_copy(storage, "images/bad.png", 128, 96, 64)
    with pytest.raises(NotFoundError, match=r"'images/bad\.png in storage' cannot be decoded"):
        ensure_working_copy(storage, "images/bad.png", 128, 96, 64, mask=True)
