"""What an export needs to know about one accepted sample: plain values, no database and no torch, so the
server side (backend/services/exports/export.py) can build them and the writers can be tested without a server."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.geometry.camera import Camera
from workers.handmodel.params import NUM_PARAMS, HandParams


@dataclass(frozen=True, eq=False)
class ViewRecord(Camera):
    """One camera's image of the sample: the camera (workers.geometry.camera.Camera: name, width and height in
    pixels, K (3, 3) pixels, dist (5,) OpenCV k1 k2 p1 p2 k3, R (3, 3) and t (3,) metres world -> camera) and
    where its files are.

    Attributes:
        image_key: storage key of the image.
        foreground_mask_key: storage key of the newest foreground mask (chroma key or an annotator's
            correction: hand, forearm and held object), or None; the alpha for Cut&Paste.
    """

    image_key: str = ""
    foreground_mask_key: str | None = None


@dataclass(frozen=True, eq=False)
class SampleRecord:
    """One accepted multi-view sample and the fit it was accepted with.

    Attributes:
        sample_id, fit_id: database ids.
        sequence: the sequence's external id.  frame_index: frame number in the sequence.
        split: "train" or "evaluation" (FreiHAND: green-screen recordings train).
        green_screen: recorded in front of the green screen (its images can be composited).
        round_index, stream: the round D_i it joined and by which stream (heuristic, manual, annotated).
        params: (61,) theta of the fit (docs/conventions.md; `hand_params` splits it).
        keypoints_m: (21, 3) the fit's keypoints, metres, world frame, FreiHAND order.
        model_file: the hand model that made the fit (as the fit records it).
        views: the sample's views in camera order.
        fit_source: what the fit was made from (its inputs' source): annotators' clicks, MVNet's prediction, or
            the pretrained detector (pre-annotation, round 0 without clicks).
        side: the hand, "right" or "left" (its sequence's): which hand model `params` pose.
    """

    sample_id: int
    fit_id: int
    sequence: str
    frame_index: int
    split: str
    green_screen: bool
    round_index: int
    stream: str
    params: np.ndarray
    keypoints_m: np.ndarray
    model_file: str
    views: tuple[ViewRecord, ...]
    fit_source: str = "unknown"  # what the fit was made from: "annotation", "prediction" or "detector"
    side: str = "right"

    def __post_init__(self) -> None:
        if self.side not in ("right", "left"):
            raise ValueError(f"sample {self.sample_id}: side must be 'right' or 'left', got {self.side!r}")
        if np.shape(self.params) != (NUM_PARAMS,):
            raise ValueError(f"sample {self.sample_id}: params must have shape ({NUM_PARAMS},), "
                             f"got {np.shape(self.params)}")
        if np.shape(self.keypoints_m) != (21, 3):
            raise ValueError(f"sample {self.sample_id}: keypoints_m must have shape (21, 3), "
                             f"got {np.shape(self.keypoints_m)}")
        if not (np.isfinite(self.params).all() and np.isfinite(self.keypoints_m).all()):
            raise ValueError(f"sample {self.sample_id}: the fit contains non-finite numbers")

    @property
    def hand_params(self) -> HandParams:
        """The fit's parameters split (betas, pose, global_orient, transl)."""
        return HandParams.from_theta(self.params)
