"""The capture format's constants, keys and in-memory records (docs/capture-format.md).

A capture is a directory; `reader.read_capture` turns it into the frozen records below and
`writer` writes them. Every path below is relative to the capture root.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from workers.geometry.camera import Camera
from workers.handmodel.params import HandParams

FORMAT_NAME = "handloop-capture"
FORMAT_VERSION = 2
# Keys added in version 2 (bring-your-own-rig captures); version-1 files must not carry them.
VERSION_2_CAPTURE_KEYS = frozenset({"working_width_px"})
VERSION_2_SEQUENCE_KEYS = frozenset({"chroma_key", "hand_side"})

CAPTURE_FILE = "capture.json"
CALIBRATION_FILE = "calibration.json"
SUBJECTS_FILE = "subjects.json"
SEQUENCES_DIR = "sequences"
SEQUENCE_FILE = "sequence.json"
IMAGES_DIR = "images"
MASKS_DIR = "masks"
GROUND_TRUTH_DIR = "ground_truth"
GT_MASKS_DIR = "masks"  # inside ground_truth/
FRAME_DIGITS = 6
IMAGE_FORMATS = ("jpg", "png")
SPLITS = ("train", "evaluation")

# JSON keys: required and optional per file. Anything else is an error (catches typos early).
CAPTURE_KEYS_REQUIRED = frozenset({"format", "version", "name", "synthetic", "hand_model"})
CAPTURE_KEYS_OPTIONAL = frozenset({"description", "generator"}) | VERSION_2_CAPTURE_KEYS
HAND_MODEL_KEYS_REQUIRED = frozenset({"name", "is_mano", "side"})
HAND_MODEL_KEYS_OPTIONAL = frozenset({"num_vertices", "source_note"})
SUBJECT_KEYS_REQUIRED = frozenset({"id"})
SUBJECT_KEYS_OPTIONAL = frozenset({"betas", "skin_tone", "sex", "notes"})
SEQUENCE_KEYS_REQUIRED = frozenset({"id", "subject", "split", "green_screen", "fps", "num_frames",
                                    "holds_object", "image_format"})
SEQUENCE_KEYS_OPTIONAL = frozenset({"object", "background", "notes"}) | VERSION_2_SEQUENCE_KEYS

# Arrays of a ground-truth file: name -> (shape with -1 for V and C, dtype kind).
GT_ARRAYS: dict[str, tuple[tuple[int, ...], str]] = {
    "betas": ((10,), "f"),
    "pose": ((45,), "f"),
    "global_orient": ((3,), "f"),
    "transl": ((3,), "f"),
    "keypoints_3d": ((21, 3), "f"),
    "vertices": ((-1, 3), "f"),
    "keypoints_2d": ((-2, 21, 2), "f"),
    "visibility": ((-2, 21), "b"),
    "camera_names": ((-2,), "U"),
}

ID_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


class CaptureError(ValueError):
    """A capture on disk is malformed; the message names the file and the field at fault."""


def frame_name(index: int) -> str:
    """File stem of frame `index`: zero-padded to six digits, e.g. 7 -> '000007'."""
    return f"{index:0{FRAME_DIGITS}d}"


@dataclass(frozen=True)
class HandModelInfo:
    """Which hand model the capture's parameters refer to.

    Attributes:
        name: e.g. "MANO_RIGHT.pkl" or "handloop-builtin v1".
        is_mano: True for the official licensed MANO model.
        side: "right" or "left".
        num_vertices: vertex count of the model's mesh (checks ground-truth vertices), or None.
        source_note: free text shown in the UI and exports.
    """

    name: str
    is_mano: bool
    side: str = "right"
    num_vertices: int | None = None
    source_note: str = ""


@dataclass(frozen=True)
class Subject:
    """A person (or synthetic subject).

    Attributes:
        id: unique id, [A-Za-z0-9][A-Za-z0-9_.-]*.
        betas: (10,) float64 shape coefficients when known (synthetic), else None.
        skin_tone: sRGB hex colour such as "#a07e56" when known, else None.
        sex: free text or None.
        notes: free text.
    """

    id: str
    betas: np.ndarray | None = None
    skin_tone: str | None = None
    sex: str | None = None
    notes: str = ""


@dataclass(frozen=True)
class FrameRef:
    """Where one synchronized multi-view frame lives on disk.

    Attributes:
        sequence_id: the sequence's id.
        index: frame number within the sequence, 0-based.
        time_s: index / fps, seconds from the sequence start.
        image_paths: camera name -> image file, for every camera of the calibration.
        mask_paths: camera name -> foreground (chroma-key) mask, empty when the sequence has none.
        ground_truth_path: the frame's ground-truth .npz, or None.
        gt_mask_paths: camera name -> ground-truth hand mask, empty without ground truth.
    """

    sequence_id: str
    index: int
    time_s: float
    image_paths: dict[str, Path]
    mask_paths: dict[str, Path]
    ground_truth_path: Path | None
    gt_mask_paths: dict[str, Path] = field(default_factory=dict)


@dataclass(frozen=True)
class Sequence:
    """A continuous recording of one subject.

    Attributes:
        id: unique id, equal to its folder name under sequences/.
        subject_id: a Subject.id of the capture.
        split: "train" (green screen) or "evaluation".
        green_screen: recorded in front of the green screen.
        fps: frames per second.
        holds_object: the subject holds an object.
        frames: the frames in order, frames[i].index == i.
        object_kind: what is held (free text, e.g. "cylinder"), or None.
        background: free-text description of the background, e.g. "green screen", "photo:brick".
        image_format: "jpg" or "png".
        chroma_key: the keyer settings the masks were made with (workers.capture.chroma.ChromaKey as a
            dict; version 2), or None.
        hand_side: "right" or "left" where this sequence's hand differs from the capture's
            hand_model.side (version 2), or None: the capture's.
    """

    id: str
    subject_id: str
    split: str
    green_screen: bool
    fps: float
    holds_object: bool
    frames: tuple[FrameRef, ...]
    object_kind: str | None = None
    background: str = ""
    image_format: str = "jpg"
    chroma_key: dict[str, Any] | None = None
    hand_side: str | None = None

    @property
    def has_masks(self) -> bool:
        return bool(self.frames and self.frames[0].mask_paths)

    @property
    def has_ground_truth(self) -> bool:
        return bool(self.frames and self.frames[0].ground_truth_path is not None)


@dataclass(frozen=True)
class Capture:
    """A validated capture directory.

    Attributes:
        root: the capture directory.
        name: human-readable name.
        cameras: the calibrated views, in calibration order (the order of every per-view array).
        subjects: subject id -> Subject.
        sequences: the sequences sorted by id.
        hand_model: the hand model the ground truth refers to (real captures: the one to fit).
        synthetic: True for captures written by `handloop synth`.
        working_width_px: the image width networks and thumbnails derive their inputs at (images stay at
            full resolution; version 2), or None: use the images as they are.
    """

    root: Path
    name: str
    cameras: tuple[Camera, ...]
    subjects: dict[str, Subject]
    sequences: tuple[Sequence, ...]
    hand_model: HandModelInfo
    synthetic: bool
    working_width_px: int | None = None

    @property
    def camera_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.cameras)

    def sequence(self, sequence_id: str) -> Sequence:
        """The sequence with this id (KeyError naming the known ids otherwise)."""
        for seq in self.sequences:
            if seq.id == sequence_id:
                return seq
        raise KeyError(f"no sequence {sequence_id!r}; known: {[s.id for s in self.sequences]}")


@dataclass(frozen=True)
class GroundTruth:
    """Ground truth of one frame (synthetic captures). Per-view arrays follow the calibration order.

    Attributes:
        betas: (10,) float64 shape coefficients.
        pose: (45,) float64 articulation, axis-angle per joint, radians (MANO joint order).
        global_orient: (3,) float64 axis-angle rotation of the wrist, model -> world, radians.
        transl: (3,) float64 translation, metres, world frame.
        keypoints_3d: (21, 3) float64 keypoints in FreiHAND order, metres, world frame.
        vertices: (V, 3) float64 hand mesh vertices, metres, world frame.
        keypoints_2d: (C, 21, 2) float64 projected keypoints (with distortion), pixels.
        visibility: (C, 21) bool, keypoint inside the image and not occluded (by the object, the
            forearm or other parts of the hand).
        camera_names: (C,) the view order.
        hand_masks: camera name -> (H, W) bool visible hand pixels (hand mesh only; stops at the wrist).
    """

    betas: np.ndarray
    pose: np.ndarray
    global_orient: np.ndarray
    transl: np.ndarray
    keypoints_3d: np.ndarray
    vertices: np.ndarray
    keypoints_2d: np.ndarray
    visibility: np.ndarray
    camera_names: tuple[str, ...]
    hand_masks: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def params(self) -> HandParams:
        """The true parameters as one value; `.to_theta()` gives the 61-value vector a fit stores."""
        return HandParams(self.betas, self.pose, self.global_orient, self.transl)
