"""A stand-in for the pretrained detector in job-layer tests: the synthetic capture's ground truth plus noise.

Per view, the true 2D keypoints plus Gaussian noise; `outlier_views` views per frame (or `outliers_by_frame`)
are shifted far off (a wrong detection the triangulation must reject); views in `missing_views` find no hand.
The lifting is the real robust triangulation (workers.geometry.triangulation). Frames are recognised by the
bytes of their first view's image, so the fake needs nothing the real `detect_frame` is not given.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from workers.detector.types import LiftedKeypoints, ViewKeypoints


def _key(image: np.ndarray) -> str:
    return hashlib.sha1(np.ascontiguousarray(image).tobytes()).hexdigest()


@dataclass
class FakeDetector:
    """Callable like workers.tasks.preannotate.detect. `calls` counts frames it was asked about."""

    capture_dir: Path
    noise_px: float = 1.0
    outlier_views: int = 1
    outlier_shift_px: float = 40.0
    missing_views: tuple[int, ...] = ()
    no_hand_frames: set[int] = field(default_factory=set)  # frame indices where nothing is found
    outliers_by_frame: dict[int, int] = field(default_factory=dict)  # frame index -> outlier views (else outlier_views)
    seed: int = 0
    calls: int = 0

    def __post_init__(self) -> None:
        from workers.capture import load_ground_truth, read_capture
        from workers.capture.reader import load_frame_images

        capture = read_capture(self.capture_dir)
        self.cameras = list(capture.cameras)
        self.truth = {}
        for sequence in capture.sequences:
            for frame in sequence.frames:
                first = load_frame_images(frame, capture.cameras)[capture.cameras[0].name]
                self.truth[_key(first)] = (frame.index, load_ground_truth(frame))
        self.rng = np.random.default_rng(self.seed)

    def __call__(self, images: Sequence[np.ndarray], cameras: Sequence, masks: Sequence | None = None, *,
                 handedness: str = "right") -> LiftedKeypoints:
        from workers.geometry.triangulation import triangulate

        self.calls += 1
        index, truth = self.truth[_key(images[0])]
        C = len(cameras)
        pixels = np.asarray(truth.keypoints_2d, float) + self.rng.normal(0.0, self.noise_px, (C, 21, 2))
        n_outliers = self.outliers_by_frame.get(index, self.outlier_views)
        outliers = self.rng.choice(C, size=n_outliers, replace=False) if n_outliers else []
        for c in outliers:
            pixels[c] += self.outlier_shift_px
        views: list[ViewKeypoints | None] = []
        for c in range(C):
            if c in self.missing_views or index in self.no_hand_frames:
                views.append(None)
                pixels[c] = np.nan
                continue
            xy = pixels[c]
            box = np.array([xy[:, 0].min(), xy[:, 1].min(), np.ptp(xy[:, 0]), np.ptp(xy[:, 1])])
            views.append(ViewKeypoints(xy.copy(), np.full(21, 0.9), 0.95, handedness, box, 0.0))
        tri = triangulate(pixels, list(cameras), outlier_px=8.0)
        agree = tri.inliers.sum(0) / C
        confidence = np.where(tri.valid, 0.5 + 0.5 * agree, np.nan)
        return LiftedKeypoints(tri.points_world, confidence, tri.inliers.T.copy(), tri.reprojection_px, tuple(views))
