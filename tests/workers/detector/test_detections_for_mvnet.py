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


def test_worker_path_with_a_detector_backed_mvnet(require_detector, rendered_capture, tmp_path):
    """predict_frames feeds a detector-backed MVNet the detections (chroma-key masks, cached) and centres its grid
    on them; untrained, its head adds nothing, so the keypoints are the triangulation of the detector's maps."""
    from dataclasses import replace

    import torch

    from workers.nets.configs import get_config
    from workers.nets.mvnet import MVNet
    from workers.nets.predict import predict_frames

    capture = read_capture(rendered_capture)
    frames = [f for s in capture.sequences for f in s.frames]
    config = replace(get_config("tiny").mvnet, heatmap_residual=True, heatmap_source="detector")
    torch.manual_seed(0)
    cache = DetectionCache(tmp_path)
    out = predict_frames(MVNet(config).eval(), frames, list(capture.cameras), detection_cache=cache)
    assert len(list(tmp_path.glob("*.npz"))) == len(frames)
    for i, frame in enumerate(frames):
        gt = load_ground_truth(frame)
        found = cache.get(frame, "chroma", "right")
        np.testing.assert_allclose(out.keypoints.centers_world[i], found.center_world())
        error_mm = 1000 * np.linalg.norm(out.keypoints.keypoints_3d[i] - gt.keypoints_3d, axis=-1)
        assert np.median(error_mm) < 30, error_mm  # tiny's grid: 25 mm voxels
        assert 0 < out.keypoints.sample_confidence[i] <= 1.5
