"""The detector's output as MVNet takes it (workers/nets/detections.py) on a rendered hand: one detection per frame,
kept in the cache and read back instead of detecting again; the grid centre from the lifted keypoints; the maps'
weights zero where a view found nothing."""

from __future__ import annotations

import numpy as np
import pytest

from workers.capture.reader import load_ground_truth, read_capture
from workers.nets import detections as detections_module
from workers.nets.detections import DetectionCache, FrameDetections, detect_frames


def test_detections_are_cached_per_frame(require_detector, rendered_capture, tmp_path, monkeypatch):
    capture = read_capture(rendered_capture)
    frames = [f for s in capture.sequences for f in s.frames]
    cameras = list(capture.cameras)
    cache = DetectionCache(tmp_path / "cache")
    first = detect_frames(frames, cameras, cache=cache)
    assert len(first) == len(frames) and len(list((tmp_path / "cache").glob("*.npz"))) == len(frames)
    for frame, found in zip(frames, first, strict=True):
        gt = load_ground_truth(frame)
        assert found.keypoints_px.shape == (len(cameras), 21, 2) and found.scores.shape == (len(cameras), 21)
        assert np.all((found.scores >= 0) & (found.scores <= 1))
        assert np.all(found.scores[~np.isfinite(found.keypoints_px).all(-1)] == 0)
        center = found.center_world()
        assert center is not None
        assert np.linalg.norm(center - np.median(gt.keypoints_3d, axis=0)) < 0.03  # within 3 cm of the hand's
    # Read back, not detected again; other masks are another entry.
    import workers.detector as detector

    def refuse(*args, **kwargs):
        raise AssertionError("detected again although cached")

    monkeypatch.setattr(detector, "detect_frame", refuse, raising=False)
    monkeypatch.setattr(detector.pipeline, "detect_frame", refuse)
    again = detect_frames(frames, cameras, cache=cache)
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a.keypoints_px, b.keypoints_px)
        np.testing.assert_array_equal(a.scores, b.scores)
        np.testing.assert_array_equal(a.points_world, b.points_world)
    with pytest.raises(AssertionError, match="detected again"):
        detect_frames(frames[:1], cameras, cache=cache, masks=lambda _f: None, masks_label="none")


def test_a_corrupt_cache_entry_is_detected_again(tmp_path):
    cache = DetectionCache(tmp_path)
    empty = FrameDetections.empty(3)
    assert empty.center_world() is None and np.all(empty.scores == 0)

    class Frame:  # the cache needs only these fields of a FrameRef
        sequence_id, index, image_paths = "s", 1, {}

    cache.put(Frame, "chroma", "right", empty)  # type: ignore[arg-type]
    assert cache.get(Frame, "chroma", "right") is not None  # type: ignore[arg-type]
    cache.path(Frame, "chroma", "right").write_bytes(b"junk")  # type: ignore[arg-type]
    assert cache.get(Frame, "chroma", "right") is None  # type: ignore[arg-type]
    assert detections_module.CACHE_VERSION >= 1
