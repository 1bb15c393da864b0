"""The networks' and the detector's inputs at the project's working resolution (issue 18), and their outputs
back in full-resolution pixels.

A project with a working width W narrower than its cameras has its views read by HandSegNet, MVNet (training
and prediction) and the detector from working copies in storage (`derived-v2/w<W>/...`, the copies the UI
shows, derived once and again when stale: backend.services.captures.working_images), with the cameras scaled alike
(`Camera.scaled`). What leaves for storage or the fits is mapped back: HandSegNet's masks resized to the
views' full size, the detector's keypoints and boxes to full-resolution pixels (workers/capture/working.py)
and its residuals measured again in them. 3D outputs (MVNet's keypoints, lifted points) are in metres and need nothing.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from sqlalchemy.orm import Session

from backend.services.captures.working_images import ensure_working_copy, project_working_width
from workers.capture.working import (
    is_reduced,
    mask_to_working,
    probabilities_to_full,
    to_full_length_px,
    to_full_px,
    working_cameras,
)
from workers.detector.types import LiftedKeypoints, ViewKeypoints
from workers.geometry.camera import Camera
from workers.geometry.projection import project_points
from workers.tasks.context import WorkerContext
from workers.tasks.inputs import Rig, SampleFrame


@dataclass(frozen=True, eq=False)
class WorkingRig:
    """A rig as the networks see it.

    Attributes:
        width: the project's working width, or None when every view is read as stored.
        full: the calibrated cameras (full resolution: clicks, stored masks, fits).
        cameras: the same cameras at the working resolution (`full` itself where not reduced).
    """

    width: int | None
    full: tuple[Camera, ...]
    cameras: tuple[Camera, ...]

    @property
    def reduced(self) -> bool:
        return is_reduced(self.full, self.width)


def working_rig(session: Session, rig: Rig) -> WorkingRig:
    """The project's working width applied to its rig."""
    width = project_working_width(session, rig.project_id)
    return WorkingRig(width, rig.cameras, working_cameras(rig.cameras, width))


def _storage_key(ctx: WorkerContext, path: Path) -> str:
    return Path(path).relative_to(ctx.storage.root).as_posix()  # type: ignore[attr-defined]


def working_frame(ctx: WorkerContext, frame: SampleFrame, wrig: WorkingRig, with_masks: bool = True) -> SampleFrame:
    """`frame` with its image and (`with_masks`) chroma-key mask files replaced by their working copies (derived
    into storage when missing or stale); `frame` itself when the rig is not reduced."""
    if not wrig.reduced:
        return frame
    assert wrig.width is not None
    ref = frame.frame
    images, masks = dict(ref.image_paths), dict(ref.mask_paths)
    for full, small in zip(wrig.full, wrig.cameras, strict=True):
        if small is full:
            continue
        images[full.name] = ctx.storage_path(ensure_working_copy(
            ctx.storage, _storage_key(ctx, ref.image_paths[full.name]), full.width, full.height, wrig.width))
        if with_masks and full.name in ref.mask_paths:
            masks[full.name] = ctx.storage_path(ensure_working_copy(
                ctx.storage, _storage_key(ctx, ref.mask_paths[full.name]), full.width, full.height, wrig.width,
                mask=True))
    return dataclasses.replace(frame, frame=dataclasses.replace(ref, image_paths=images, mask_paths=masks))


def working_frames(ctx: WorkerContext, frames: Sequence[SampleFrame], wrig: WorkingRig,
                   progress: Callable[[int], None] | None = None) -> list[SampleFrame]:
    """`working_frame` of each frame; `progress(frames done)` after each (deriving a frame's copies takes
    ~25 ms per 2048 px view: a job's progress, which is its heartbeat, keeps moving)."""
    out = []
    for frame in frames:
        out.append(working_frame(ctx, frame, wrig))
        if progress is not None:
            progress(len(out))
    return out


def working_masks(masks: Sequence[np.ndarray | None], wrig: WorkingRig) -> list[np.ndarray | None]:
    """Full-resolution (H, W) masks in camera order -> (h, w) bool at the working size (None stays None)."""
    return [None if m is None else mask_to_working(m, small) for m, small in zip(masks, wrig.cameras, strict=True)]


def working_mask_dicts(masks: Sequence[Mapping[str, np.ndarray]] | None, wrig: WorkingRig
                       ) -> list[dict[str, np.ndarray]] | None:
    """Per frame camera name -> full-resolution mask, as working-size masks (training labels)."""
    if masks is None or not wrig.reduced:
        return None if masks is None else [dict(m) for m in masks]
    by_name = {c.name: c for c in wrig.cameras}
    return [{name: mask_to_working(m, by_name[name]) for name, m in frame.items()} for frame in masks]


def working_rig_record(rig: Rig, wrig: WorkingRig) -> Rig:
    """`rig` with the working cameras (its digest marked with the width, for caches keyed by rig)."""
    if not wrig.reduced:
        return rig
    return dataclasses.replace(rig, cameras=wrig.cameras, digest=f"{rig.digest}@w{wrig.width}")


def probabilities_at_full_resolution(maps: Sequence[np.ndarray], wrig: WorkingRig) -> list[np.ndarray]:
    """HandSegNet's C probability maps at the working size -> at the views' full size (camera order)."""
    return [probabilities_to_full(p, full) for p, full in zip(maps, wrig.full, strict=True)]


def lifted_at_full_resolution(lifted: LiftedKeypoints, wrig: WorkingRig) -> LiftedKeypoints:
    """The detector's answer on working copies with pixels in full-resolution pixels: per view keypoints and
    box exactly; the reprojection residual ((21,), the median over each keypoint's inlier views) measured
    again in each view's full-resolution pixels (a rig of mixed widths scales its views differently)."""
    if not wrig.reduced:
        return lifted
    views: list[ViewKeypoints | None] = []
    for view, small, full in zip(lifted.views, wrig.cameras, wrig.full, strict=True):
        if view is None or small is full:
            views.append(view)
            continue
        box = np.asarray(view.box_px, np.float64)
        corner = to_full_px(box[:2], small, full)
        size = to_full_length_px(box[2:], small, full)
        views.append(dataclasses.replace(view, keypoints_px=to_full_px(view.keypoints_px, small, full),
                                         box_px=np.concatenate([corner, size])))
    return dataclasses.replace(lifted, views=tuple(views),
                               reprojection_px=_median_residual_px(lifted, views, wrig.full))


def _median_residual_px(lifted: LiftedKeypoints, views: Sequence[ViewKeypoints | None],
                        cameras: Sequence[Camera]) -> np.ndarray:
    """(K,) median over each lifted keypoint's inlier views of |projection - detection|, in the pixels of
    `views` and `cameras` (NaN where the detector lifted none)."""
    residual = np.full(len(lifted.reprojection_px), np.nan)
    lifted_rows = np.flatnonzero(np.isfinite(lifted.reprojection_px) & lifted.inliers.any(axis=1))
    if lifted_rows.size == 0:
        return residual
    projected, _ = project_points(lifted.points_world[lifted_rows], list(cameras))  # (C, N, 2)
    for c, view in enumerate(views):
        if view is None:
            projected[c] = np.nan
        else:
            projected[c] -= np.asarray(view.keypoints_px, np.float64)[lifted_rows]
    error = np.linalg.norm(projected, axis=2).T  # (N, C)
    for row, k in enumerate(lifted_rows):
        residual[k] = float(np.median(error[row, lifted.inliers[k]]))
    return residual
