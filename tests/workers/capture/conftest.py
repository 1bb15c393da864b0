"""A tiny valid capture written with the writer (no renderer): 8 views at 48 px, 2 sequences x 2 frames,
PNG images (exact round trip), masks and ground truth on the first sequence."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from workers.capture import GroundTruth, HandModelInfo, Subject, write_capture_header, write_frame, write_sequence
from workers.geometry import default_rig

NUM_VERTICES = 12


def _ground_truth(cameras, rng: np.random.Generator) -> GroundTruth:
    C = len(cameras)
    return GroundTruth(
        betas=rng.normal(size=10), pose=rng.normal(size=45) * 0.1, global_orient=rng.normal(size=3),
        transl=rng.normal(size=3) * 0.01, keypoints_3d=rng.normal(size=(21, 3)) * 0.05,
        vertices=rng.normal(size=(NUM_VERTICES, 3)) * 0.05, keypoints_2d=rng.uniform(0, 40, (C, 21, 2)),
        visibility=rng.random((C, 21)) > 0.3, camera_names=tuple(c.name for c in cameras),
        hand_masks={c.name: rng.random((c.height, c.width)) > 0.5 for c in cameras},
    )


def build_capture(root: Path) -> dict:
    """Write the tiny capture; returns what was written, for comparisons."""
    rng = np.random.default_rng(0)
    cameras = default_rig(48)
    subjects = [Subject("subj00", betas=np.arange(10) / 10, skin_tone="#a07e56"), Subject("subj01")]
    write_capture_header(root, "tiny", cameras, subjects,
                         HandModelInfo("test-model", is_mano=False, num_vertices=NUM_VERTICES), synthetic=True)
    names = [c.name for c in cameras]
    written: dict = {"cameras": cameras, "images": {}, "gt": {}}
    for seq, subject, with_extras in (("seq000", "subj00", True), ("seq001", "subj01", False)):
        write_sequence(root, seq, subject_id=subject, split="train" if with_extras else "evaluation",
                       green_screen=with_extras, fps=15.0, num_frames=2, holds_object=not with_extras,
                       camera_names=names, image_format="png", object_kind=None if with_extras else "ball",
                       with_masks=with_extras, with_ground_truth=with_extras)
        for f in range(2):
            images = {c.name: rng.integers(0, 256, (c.height, c.width, 3), dtype=np.uint8) for c in cameras}
            masks = {c.name: rng.random((c.height, c.width)) > 0.5 for c in cameras} if with_extras else None
            gt = _ground_truth(cameras, rng) if with_extras else None
            write_frame(root, seq, f, images, image_format="png", masks=masks, ground_truth=gt)
            written["images"][(seq, f)] = images
            written["gt"][(seq, f)] = gt
    return written


@pytest.fixture
def tiny_capture(tmp_path: Path) -> tuple[Path, dict]:
    root = tmp_path / "capture"
    return root, build_capture(root)
