"""Write captures in the handloop capture format (docs/capture-format.md).

Writing is split so that several processes can fill one capture: `write_capture_header` once, then
`write_sequence` per sequence, then `write_frame` per frame from any process (each frame owns its
files). Images are stored as JPEG (quality 92) or PNG; masks as 8-bit PNG, 0 / 255.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from workers.capture.schema import (
    CALIBRATION_FILE,
    CAPTURE_FILE,
    FORMAT_NAME,
    FORMAT_VERSION,
    GROUND_TRUTH_DIR,
    GT_MASKS_DIR,
    IMAGES_DIR,
    MASKS_DIR,
    SEQUENCE_FILE,
    SEQUENCES_DIR,
    SUBJECTS_FILE,
    GroundTruth,
    HandModelInfo,
    Subject,
    frame_name,
)
from workers.geometry.camera import Camera, save_calibration

JPEG_QUALITY = 92
# PNG compression 1: masks are tiny and mostly constant; higher levels cost time for ~no gain.
PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 1]


def _write_json(path: Path, data: dict[str, Any]) -> None:
    path.write_text(json.dumps(data, indent=1, allow_nan=False) + "\n")


def write_capture_header(root: Path, name: str, cameras: list[Camera], subjects: list[Subject],
                         hand_model: HandModelInfo, synthetic: bool, *, description: str = "",
                         generator: dict[str, Any] | None = None, working_width_px: int | None = None) -> None:
    """Create `root` (it may exist and be empty) with capture.json, calibration.json, subjects.json.

    `working_width_px` (a version-2 key) is written only when given; without it the capture is version 1,
    which older readers accept.
    """
    root = Path(root)
    (root / SEQUENCES_DIR).mkdir(parents=True, exist_ok=True)
    model: dict[str, Any] = {"name": hand_model.name, "is_mano": hand_model.is_mano, "side": hand_model.side,
                             "source_note": hand_model.source_note}
    if hand_model.num_vertices is not None:
        model["num_vertices"] = int(hand_model.num_vertices)
    header: dict[str, Any] = {"format": FORMAT_NAME, "version": 1, "name": name,
                              "synthetic": bool(synthetic), "hand_model": model}
    if working_width_px is not None:
        header["version"] = FORMAT_VERSION
        header["working_width_px"] = int(working_width_px)
    if description:
        header["description"] = description
    if generator is not None:
        header["generator"] = generator
    _write_json(root / CAPTURE_FILE, header)
    save_calibration(list(cameras), root / CALIBRATION_FILE)
    rows = []
    for s in subjects:
        row: dict[str, Any] = {"id": s.id}
        if s.betas is not None:
            row["betas"] = [float(b) for b in s.betas]
        if s.skin_tone is not None:
            row["skin_tone"] = s.skin_tone
        if s.sex is not None:
            row["sex"] = s.sex
        if s.notes:
            row["notes"] = s.notes
        rows.append(row)
    _write_json(root / SUBJECTS_FILE, {"subjects": rows})


def write_sequence(root: Path, sequence_id: str, *, subject_id: str, split: str, green_screen: bool,
                   fps: float, num_frames: int, holds_object: bool, camera_names: list[str],
                   image_format: str = "jpg", object_kind: str | None = None, background: str = "",
                   with_masks: bool = False, with_ground_truth: bool = False,
                   chroma_key: dict[str, Any] | None = None, hand_side: str | None = None) -> Path:
    """Write sequences/<id>/sequence.json and create its folders; returns the sequence folder.

    `chroma_key` (the keyer settings of the masks) and `hand_side` (this sequence's hand where it differs
    from the capture's hand_model.side), version-2 keys, need a version-2 capture.json.
    """
    if hand_side is not None and hand_side not in ("right", "left"):
        raise ValueError(f"hand_side must be 'right' or 'left', got {hand_side!r}")
    if not math.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be a positive number, got {fps}")
    seq_dir = Path(root) / SEQUENCES_DIR / sequence_id
    data: dict[str, Any] = {"id": sequence_id, "subject": subject_id, "split": split,
                            "green_screen": bool(green_screen), "fps": float(fps), "num_frames": int(num_frames),
                            "holds_object": bool(holds_object), "image_format": image_format}
    if object_kind is not None:
        data["object"] = object_kind
    if background:
        data["background"] = background
    if chroma_key is not None:
        data["chroma_key"] = dict(chroma_key)
    if hand_side is not None:
        data["hand_side"] = hand_side
    for cam in camera_names:
        (seq_dir / IMAGES_DIR / cam).mkdir(parents=True, exist_ok=True)
        if with_masks:
            (seq_dir / MASKS_DIR / cam).mkdir(parents=True, exist_ok=True)
        if with_ground_truth:
            (seq_dir / GROUND_TRUTH_DIR / GT_MASKS_DIR / cam).mkdir(parents=True, exist_ok=True)
    _write_json(seq_dir / SEQUENCE_FILE, data)
    return seq_dir


def _imwrite(path: Path, image: np.ndarray, params: list[int] | None = None) -> None:
    if not cv2.imwrite(str(path), image, params or []):
        raise OSError(f"{path}: could not write image")


def write_frame(root: Path, sequence_id: str, index: int, images: dict[str, np.ndarray], *,
                image_format: str = "jpg", masks: dict[str, np.ndarray] | None = None,
                ground_truth: GroundTruth | None = None) -> None:
    """Write one frame's files.

    Args:
        root: capture directory (header and sequence already written).
        sequence_id, index: which frame.
        images: camera name -> (H, W, 3) uint8 RGB.
        image_format: "jpg" or "png", as in sequence.json.
        masks: camera name -> (H, W) bool foreground mask, or None.
        ground_truth: the frame's ground truth (its hand_masks are written as PNGs), or None.
    """
    seq_dir = Path(root) / SEQUENCES_DIR / sequence_id
    stem = frame_name(index)
    params = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if image_format == "jpg" else PNG_PARAMS
    for cam, rgb in images.items():
        _imwrite(seq_dir / IMAGES_DIR / cam / f"{stem}.{image_format}", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params)
    for cam, mask in (masks or {}).items():
        _imwrite(seq_dir / MASKS_DIR / cam / f"{stem}.png", mask.astype(np.uint8) * 255, PNG_PARAMS)
    if ground_truth is not None:
        gt = ground_truth
        np.savez(seq_dir / GROUND_TRUTH_DIR / f"{stem}.npz", betas=gt.betas, pose=gt.pose,
                 global_orient=gt.global_orient, transl=gt.transl, keypoints_3d=gt.keypoints_3d,
                 vertices=gt.vertices.astype(np.float32), keypoints_2d=gt.keypoints_2d,
                 visibility=gt.visibility.astype(bool), camera_names=np.asarray(gt.camera_names))
        for cam, mask in gt.hand_masks.items():
            _imwrite(seq_dir / GROUND_TRUTH_DIR / GT_MASKS_DIR / cam / f"{stem}.png",
                     mask.astype(np.uint8) * 255, PNG_PARAMS)
