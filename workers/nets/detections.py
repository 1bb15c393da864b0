"""The detector's output as MVNet's input (heatmap_source = "detector"): per frame once, cached on disk.

A detection costs ~26 ms per crop and several crops per view (docs/detector.md: ~0.4 s CPU per 8-view frame), far
more than a training step, so frames are detected once (training data pipeline, prediction) and the results kept
in a cache folder, one small .npz per frame, keyed by the frame's image files (path, size, mtime), the masks that
located the hand and the handedness.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from workers.capture.reader import load_frame_images, load_frame_masks
from workers.capture.schema import FrameRef
from workers.detector.handedness import lifted_side, side_disagreement
from workers.detector.keypoint_offsets import KeypointOffsets, fit_keypoint_offsets
from workers.geometry.camera import Camera
from workers.geometry.projection import project_points
from workers.handmodel.keypoints import NUM_KEYPOINTS
from workers.nets.configs import NetsConfig, paper_only

log = logging.getLogger(__name__)

# The grid centre from the lifted keypoints needs at least this many of them (else the caller's own centre).
MIN_CENTER_KEYPOINTS = 6
CACHE_VERSION = 2  # 2: several hands per view, the requested side's kept (issue 36)


@dataclass(frozen=True, eq=False)
class FrameDetections:
    """One frame's detector output in the form MVNet takes it.

    Attributes:
        keypoints_px: (C, K, 2) float32, each view's 2D keypoints in pixels of its full image; NaN where the view
            found no hand.
        scores: (C, K) float32 in [0, 1]: the map weights, the detector's per-keypoint score (which carries the
            view's presence) where the lift used the view for that keypoint or did not lift the keypoint at all,
            0 where the lift rejected the view as an outlier and where the view found no hand.
        points_world: (K, 3) float64 lifted keypoints, metres, world frame; NaN rows where not lifted.
        confidence: (K,) float64 the lift's per-keypoint confidence (NaN where not lifted).
    """

    keypoints_px: np.ndarray
    scores: np.ndarray
    points_world: np.ndarray
    confidence: np.ndarray

    @classmethod
    def empty(cls, num_views: int) -> FrameDetections:
        """No hand found in any view."""
        return cls(np.full((num_views, NUM_KEYPOINTS, 2), np.nan, np.float32),
                   np.zeros((num_views, NUM_KEYPOINTS), np.float32), np.full((NUM_KEYPOINTS, 3), np.nan),
                   np.full(NUM_KEYPOINTS, np.nan))

    @classmethod
    def from_lifted(cls, lifted: object) -> FrameDetections:
        """From workers.detector's LiftedKeypoints (views, inliers, points_world, confidence)."""
        views = lifted.views  # type: ignore[attr-defined]
        out = cls.empty(len(views))
        lifted_k = np.isfinite(lifted.points_world).all(axis=1)  # type: ignore[attr-defined]
        for c, view in enumerate(views):
            if view is None:
                continue
            out.keypoints_px[c] = view.keypoints_px
            used = np.where(lifted_k, lifted.inliers[:, c], True)  # type: ignore[attr-defined]
            out.scores[c] = np.asarray(view.scores, np.float32) * used
        return cls(out.keypoints_px, out.scores, np.asarray(lifted.points_world, np.float64),  # type: ignore[attr-defined]
                   np.asarray(lifted.confidence, np.float64))  # type: ignore[attr-defined]

    def center_world(self) -> np.ndarray | None:
        """A robust centroid of the lifted keypoints, (3,) metres, world frame: the per-axis median; None when
        fewer than MIN_CENTER_KEYPOINTS were lifted."""
        finite = np.isfinite(self.points_world).all(axis=1)
        if finite.sum() < MIN_CENTER_KEYPOINTS:
            return None
        return np.median(self.points_world[finite], axis=0)

    def corrected(self, offsets: KeypointOffsets, cameras: Sequence[Camera]) -> FrameDetections:
        """These detections with the learned keypoint offsets applied (workers.detector.keypoint_offsets): the
        lifted keypoints moved, and each view's 2D keypoint moved by its lifted keypoint's move as that view
        sees it, so the maps MVNet unprojects meet at the corrected point. Keypoints not lifted stay."""
        moved = offsets.apply(self.points_world)
        pixels = self.keypoints_px.astype(np.float64)
        finite = np.isfinite(self.points_world).all(axis=1)
        if finite.any():
            before, _ = project_points(self.points_world[finite], list(cameras))
            after, _ = project_points(moved[finite], list(cameras))
            pixels[:, finite] += after - before  # NaN stays NaN where a view found no hand
        return FrameDetections(pixels.astype(np.float32), self.scores, moved, self.confidence)

    def to_npz(self, path: Path) -> None:
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, keypoints_px=self.keypoints_px, scores=self.scores, points_world=self.points_world,
                 confidence=self.confidence)
        os.replace(tmp, path)

    @classmethod
    def from_npz(cls, path: Path) -> FrameDetections:
        with np.load(path) as data:
            return cls(data["keypoints_px"], data["scores"], data["points_world"], data["confidence"])


def learn_detector_offsets(detections: Sequence[FrameDetections], labels_m: np.ndarray, *,
                           pose: bool = False) -> KeypointOffsets:
    """The detector's keypoint offsets learned from M labelled frames: their detections and labels (M, 21, 3)
    metres, world frame (workers.detector.keypoint_offsets.fit_keypoint_offsets; `pose`: with its pose term)."""
    if len(detections) != len(labels_m):
        raise ValueError(f"got {len(detections)} detections for {len(labels_m)} labels")
    if not len(detections):
        return KeypointOffsets.none()
    return fit_keypoint_offsets(np.stack([d.points_world for d in detections]), np.asarray(labels_m, np.float64),
                                pose=pose)


def stack_detections(detections: Sequence[FrameDetections]) -> tuple[np.ndarray, np.ndarray]:
    """(M, C, K, 2) float32 image pixels and (M, C, K) float32 scores of M frames."""
    return (np.stack([d.keypoints_px for d in detections]).astype(np.float32),
            np.stack([d.scores for d in detections]).astype(np.float32))


def detector_backed(config: NetsConfig) -> tuple[NetsConfig, str | None]:
    """`config` when its MVNet does not need the detector or the detector is installed; otherwise its paper-only
    counterpart (configs.paper_only) and a sentence saying why."""
    if config.mvnet.heatmap_source != "detector":
        return config, None
    from workers.detector import detector_status  # deferred: the detector's pipeline and runtime load on use

    status = detector_status()
    if status is None:
        return config, None
    fallback = paper_only(config)
    message = (f"the detector is not available ({status}); MVNet runs paper-only ({fallback.name!r}: the learned "
               f"2D head) instead of {config.name!r}")
    log.warning(message)
    return fallback, message


class DetectionCache:
    """Per-frame detections in `folder` (created on first write); a corrupt entry is recomputed."""

    def __init__(self, folder: Path | str) -> None:
        self.folder = Path(folder)

    def path(self, frame: FrameRef, masks_label: str, handedness: str) -> Path:
        files = []
        for cam, p in sorted(frame.image_paths.items()):
            try:
                st = Path(p).stat()
                files.append([cam, str(Path(p).resolve()), st.st_size, st.st_mtime_ns])
            except OSError:
                files.append([cam, str(p), None, None])
        key = json.dumps({"v": CACHE_VERSION, "files": files, "masks": masks_label, "hand": handedness})
        digest = hashlib.sha1(key.encode()).hexdigest()[:20]
        return self.folder / f"{frame.sequence_id}-{frame.index:06d}-{digest}.npz"

    def get(self, frame: FrameRef, masks_label: str, handedness: str) -> FrameDetections | None:
        path = self.path(frame, masks_label, handedness)
        if not path.is_file():
            return None
        try:
            return FrameDetections.from_npz(path)
        except (OSError, ValueError, KeyError) as exc:
            log.warning("detection cache entry %s unreadable (%s); detecting again", path, exc)
            return None

    def put(self, frame: FrameRef, masks_label: str, handedness: str, detections: FrameDetections) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        detections.to_npz(self.path(frame, masks_label, handedness))


def chroma_masks(frame: FrameRef, cameras: Sequence[Camera]) -> list[np.ndarray | None] | None:
    """The frame's chroma-key masks in camera order (None entries where a view has none), None without any."""
    chroma = load_frame_masks(frame) if frame.mask_paths else {}
    return [chroma.get(c.name) for c in cameras] if chroma else None


def detect_frames(frames: Sequence[FrameRef], cameras: Sequence[Camera], *, handedness: str = "right",
                  masks: Callable[[FrameRef], Sequence[np.ndarray | None] | None] | None = None,
                  masks_label: str = "chroma", cache: DetectionCache | None = None,
                  images: Callable[[FrameRef], Sequence[np.ndarray]] | None = None,
                  progress: Callable[[int], None] | None = None) -> list[FrameDetections]:
    """The detector on every frame (each once: from `cache` where it holds the frame).

    Args:
        frames: M frames of the rig `cameras`.
        handedness: "right" or "left" (the capture's hand model side).
        masks: per frame the C masks (bool (H, W) or None each) locating the hand, or None; default the chroma-key
            masks (chroma_masks). `masks_label` names them in the cache key (e.g. "chroma", "ground_truth",
            "handsegnet:<checkpoint digest>"): other masks, other detections.
        images: per frame its C images in camera order; default decoded from the frame's files.
    Returns:
        M FrameDetections (FrameDetections.empty where no view found a hand).
    Raises:
        DetectorUnavailableError: the model files are missing or corrupt.
    """
    from workers.detector import detect_frame  # deferred: the detector's pipeline and runtime load on use

    masks = masks or (lambda f: chroma_masks(f, cameras))
    out = []
    sides: dict[str, list[str | None]] = {}  # sequence -> the side each newly detected frame's hand looks like
    for frame in frames:
        found = cache.get(frame, masks_label, handedness) if cache is not None else None
        if found is None:
            views = images(frame) if images is not None else [load_frame_images(frame, cameras)[c.name]
                                                              for c in cameras]
            lifted = detect_frame(list(views), list(cameras), masks(frame),
                                  handedness=handedness)  # type: ignore[arg-type]
            sides.setdefault(frame.sequence_id, []).append(lifted_side(lifted))
            found = FrameDetections.from_lifted(lifted)
            if cache is not None:
                cache.put(frame, masks_label, handedness, found)
        out.append(found)
        if progress:
            progress(1)
    for sequence, seen in sides.items():  # the capture's declared side may be wrong (issue 36): say so
        if note := side_disagreement(seen, handedness):  # type: ignore[arg-type]
            log.warning("detections of sequence %s: %s", sequence, note)
    return out
