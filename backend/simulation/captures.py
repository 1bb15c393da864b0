"""Splitting a capture into the initial annotation set D_0 and the rest, as two captures on disk.

The server queues a whole import for annotation or none of it, and a sample queued for annotation is not
predicted by a round; so D_0 (every k-th frame of each training sequence, spread over subjects and
motions) is imported as one project queued for annotation, and the rest as another left unlabeled for the
rounds. Both are captures in the handloop format whose files are symbolic links to the original's.
Frames are renumbered without gaps; D_0's frame rate is divided by k, so its frame times equal the
original's, and the rest keeps times within one original frame interval of the truth.
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import dataclass
from pathlib import Path

from workers.capture import Capture, read_capture
from workers.capture.schema import (
    CALIBRATION_FILE,
    CAPTURE_FILE,
    GROUND_TRUTH_DIR,
    GT_MASKS_DIR,
    IMAGES_DIR,
    MASKS_DIR,
    SEQUENCE_FILE,
    SEQUENCES_DIR,
    SUBJECTS_FILE,
    frame_name,
)


@dataclass(frozen=True)
class SplitCaptures:
    """Attributes:
        initial: the D_0 capture (every `every`-th frame of each training sequence).
        rest: every other frame of the training sequences and all evaluation sequences.
        initial_frames, rest_frames: frame counts.
    """

    initial: Path
    rest: Path
    initial_frames: int
    rest_frames: int


def _link(target: Path, link: Path) -> None:
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(target.resolve())


def _write_sequence(seq_dir: Path, meta: dict, frames: list, cameras: tuple[str, ...], ext: str, fps: float) -> None:
    seq_dir.mkdir(parents=True)
    (seq_dir / SEQUENCE_FILE).write_text(json.dumps({**meta, "num_frames": len(frames), "fps": fps}, indent=1))
    for new_index, frame in enumerate(frames):
        name = frame_name(new_index)
        for cam in cameras:
            _link(frame.image_paths[cam], seq_dir / IMAGES_DIR / cam / f"{name}.{ext}")
            if cam in frame.mask_paths:
                _link(frame.mask_paths[cam], seq_dir / MASKS_DIR / cam / f"{name}.png")
            if cam in frame.gt_mask_paths:
                _link(frame.gt_mask_paths[cam], seq_dir / GROUND_TRUTH_DIR / GT_MASKS_DIR / cam / f"{name}.png")
        if frame.ground_truth_path is not None:
            _link(frame.ground_truth_path, seq_dir / GROUND_TRUTH_DIR / f"{name}.npz")


def split_capture(source: Path, out_dir: Path, every: int) -> SplitCaptures:
    """Write `out_dir/initial` and `out_dir/rest` from the capture at `source` (see the module docstring).

    Args:
        every: D_0 takes frames 0, every, 2 every, ... of each training sequence; >= 2.
    """
    if every < 2:
        raise ValueError(f"every must be at least 2 (every frame in D_0 leaves nothing to bootstrap), not {every}")
    capture: Capture = read_capture(source, check_images=False)
    if not any(seq.split == "train" for seq in capture.sequences):
        raise ValueError(f"{source}: no training sequence to take D_0 from")
    if out_dir.exists():
        shutil.rmtree(out_dir)
    roots = {"initial": out_dir / "initial", "rest": out_dir / "rest"}
    counts = dict.fromkeys(roots, 0)
    for root in roots.values():
        (root / SEQUENCES_DIR).mkdir(parents=True)
        for name in (CAPTURE_FILE, CALIBRATION_FILE, SUBJECTS_FILE):
            shutil.copyfile(capture.root / name, root / name)
    for seq in capture.sequences:
        meta = json.loads((capture.root / SEQUENCES_DIR / seq.id / SEQUENCE_FILE).read_text())
        if seq.split == "train":
            initial = [f for f in seq.frames if f.index % every == 0]
            rest = [f for f in seq.frames if f.index % every != 0]
            parts = {"initial": (initial, seq.fps / every), "rest": (rest, seq.fps * (every - 1) / every)}
        else:
            parts = {"rest": (list(seq.frames), seq.fps)}
        for which, (frames, fps) in parts.items():
            if frames:
                _write_sequence(roots[which] / SEQUENCES_DIR / seq.id, meta, frames, capture.camera_names,
                                seq.image_format, fps if math.isfinite(fps) and fps > 0 else seq.fps)
                counts[which] += len(frames)
    for root in roots.values():
        read_capture(root, check_images=False)  # the same validation the server's import applies
    return SplitCaptures(initial=roots["initial"], rest=roots["rest"], initial_frames=counts["initial"],
                         rest_frames=counts["rest"])
