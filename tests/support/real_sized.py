"""A real-sized capture for issue 18's tests: a small synthetic capture's views upscaled to 2048 px wide (3 Mpx),
with its ground truth re-projected through the scaled cameras (`Camera.scaled`) and its masks resized, and a
working width narrower than the views. Upscaled images are blurry, but every pixel size, intrinsic and label is
what a 2048 px rig gives."""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from workers.capture import (
    Capture,
    CaptureError,
    load_frame_images,
    load_frame_masks,
    load_ground_truth,
    read_capture,
    write_capture_header,
    write_frame,
    write_sequence,
)
from workers.geometry.projection import project_points

FULL_WIDTH = 2048


def _resized_mask(mask: np.ndarray, width: int, height: int) -> np.ndarray:
    return cv2.resize(mask.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST) > 0


def upscaled_capture(source: Path, out: Path, *, width: int = FULL_WIDTH, working_width_px: int = 640) -> Path:
    """`source` (a synthetic capture with ground truth) at `width` px, written to `out` (reused if present and
    whole). Written into a temporary folder beside `out` and renamed into place, so `out` is never a partial
    capture; a writer that finds `out` already renamed there by another keeps that one."""
    if out.exists():
        try:
            read_capture(out)  # images checked too: a folder left by an interrupted older writer is rebuilt
            return out
        except CaptureError:
            shutil.rmtree(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}-"))
    try:
        _write_upscaled(read_capture(source), tmp / "capture", width, working_width_px)
        try:
            (tmp / "capture").rename(out)
        except OSError:
            if not out.exists():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def _write_upscaled(capture: Capture, out: Path, width: int, working_width_px: int) -> None:
    """`capture` upscaled to `width` px, written to `out` (checked whole when written)."""
    cameras = [c.scaled(width) for c in capture.cameras]
    write_capture_header(out, f"{capture.name}-{width}px", cameras, list(capture.subjects.values()),
                         capture.hand_model, synthetic=True, working_width_px=working_width_px)
    for seq in capture.sequences:
        write_sequence(out, seq.id, subject_id=seq.subject_id, split=seq.split, green_screen=seq.green_screen,
                       fps=seq.fps, num_frames=len(seq.frames), holds_object=seq.holds_object,
                       camera_names=[c.name for c in cameras], image_format="jpg", background=seq.background,
                       with_masks=seq.has_masks, with_ground_truth=True)
        for frame in seq.frames:
            images = load_frame_images(frame, capture.cameras)
            big = {c.name: cv2.resize(images[c.name], (c.width, c.height), interpolation=cv2.INTER_CUBIC)
                   for c in cameras}
            masks = load_frame_masks(frame)
            gt = load_ground_truth(frame)
            pixels, _ = project_points(gt.keypoints_3d, cameras)
            gt = dataclasses.replace(gt, keypoints_2d=pixels, hand_masks={
                c.name: _resized_mask(gt.hand_masks[c.name], c.width, c.height) for c in cameras})
            write_frame(out, seq.id, frame.index, big, image_format="jpg",
                        masks={c.name: _resized_mask(masks[c.name], c.width, c.height) for c in cameras}
                        if masks else None, ground_truth=gt)
    read_capture(out)
