"""Ground truth for the samples a server holds, from the synthetic captures they were imported from, and
the true error of a fit (its parameters posed with the hand model, compared with the true mesh)."""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from workers.capture import Capture, FrameRef, GroundTruth, load_ground_truth
from workers.handmodel.params import NUM_PARAMS, HandParams

# Sequence kinds the report splits by (the capture's `green_screen` flag): the paper's green-screen training
# sequences, and the evaluation sequences on cluttered backgrounds.
KIND_GREEN_SCREEN, KIND_CLUTTERED = "green_screen", "cluttered"
SEQUENCE_KINDS = (KIND_GREEN_SCREEN, KIND_CLUTTERED)


class TruthError(LookupError):
    """A sample has no ground truth here (unknown project, sequence or frame)."""


@dataclass(frozen=True)
class FitError:
    """Mean vertex and keypoint errors of a fit against ground truth, millimetres."""

    vertex_mm: float
    keypoint_mm: float


class GroundTruthIndex:
    """Maps the server's sample ids to capture frames and their ground truth.

    Args:
        captures: project name -> the synthetic capture imported as that project.
        samples: rows of `GET /api/admin/exports/samples` (sample_id, project, sequence, frame_index, ...).
        mano_path: the MANO file when the captures were made with MANO; None for the built-in hand.
        cache_size: ground-truth frames kept in memory.
    """

    def __init__(self, captures: Mapping[str, Capture], samples: Iterable[Mapping[str, Any]], *,
                 mano_path: Path | None = None, cache_size: int = 64) -> None:
        self.captures = dict(captures)
        self.mano_path = mano_path
        self._frames: dict[int, tuple[Capture, FrameRef]] = {}
        self._cache: OrderedDict[int, GroundTruth] = OrderedDict()
        self._cache_size = cache_size
        self._layer = None
        self.add_samples(samples)

    def add_samples(self, samples: Iterable[Mapping[str, Any]]) -> None:
        for row in samples:
            capture = self.captures.get(row["project"])
            if capture is None:
                continue  # another project on the same server: not ours to judge
            try:
                frame = capture.sequence(row["sequence"]).frames[row["frame_index"]]
            except (KeyError, IndexError):
                raise TruthError(f"sample {row['sample_id']}: capture {capture.root} has no frame "
                                 f"{row['sequence']}/{row['frame_index']}") from None
            self._frames[int(row["sample_id"])] = (capture, frame)

    @property
    def sample_ids(self) -> list[int]:
        return sorted(self._frames)

    def __contains__(self, sample_id: int) -> bool:
        return sample_id in self._frames

    def frame(self, sample_id: int) -> tuple[Capture, FrameRef]:
        try:
            return self._frames[sample_id]
        except KeyError:
            raise TruthError(f"sample {sample_id} is not from the simulated captures") from None

    def sequence_kind(self, sample_id: int) -> str:
        """KIND_GREEN_SCREEN (a training sequence, chroma-keyed) or KIND_CLUTTERED (an evaluation sequence on a
        real background, no chroma key), from the capture's sequence metadata (`green_screen`)."""
        capture, frame = self.frame(sample_id)
        return KIND_GREEN_SCREEN if capture.sequence(frame.sequence_id).green_screen else KIND_CLUTTERED

    def truth(self, sample_id: int) -> GroundTruth:
        """The frame's ground truth (cached, most recently used kept)."""
        if sample_id in self._cache:
            self._cache.move_to_end(sample_id)
            return self._cache[sample_id]
        capture, frame = self.frame(sample_id)
        gt = load_ground_truth(frame, capture.hand_model.num_vertices)
        self._cache[sample_id] = gt
        if len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return gt

    # --- fits ------------------------------------------------------------------------------------------
    def _hand_layer(self):
        if self._layer is None:
            # deferred: torch only for fits' true errors; the simulated annotators (bench api's load driver too)
            # import this module and never pose a hand
            import torch

            from workers.handmodel.layer import HandLayer
            from workers.handmodel.loading import load_hand_model

            self._layer = HandLayer(load_hand_model(self.mano_path), dtype=torch.float64)
        return self._layer

    def pose(self, params: Sequence[Sequence[float]]) -> tuple[np.ndarray, np.ndarray]:
        """theta (B, 61) -> keypoints (B, 21, 3), vertices (B, V, 3), metres, world frame."""
        import torch  # deferred: as in _hand_layer

        hand = HandParams.from_theta(np.asarray(params, np.float64).reshape(-1, NUM_PARAMS))
        with torch.no_grad():
            out = self._hand_layer().pose_params(hand)
        return out.keypoints.numpy(), out.vertices.numpy()

    def fit_errors(self, sample_ids: Sequence[int], params: Sequence[Sequence[float]]) -> list[FitError]:
        """True errors of fits (theta (61,) each) of the given samples."""
        if len(sample_ids) != len(params):
            raise ValueError(f"{len(sample_ids)} samples but {len(params)} parameter vectors")
        if not sample_ids:
            return []
        keypoints, vertices = self.pose(params)
        out = []
        for i, sample_id in enumerate(sample_ids):
            gt = self.truth(sample_id)
            if vertices[i].shape != gt.vertices.shape:
                raise TruthError(f"sample {sample_id}: the fit's mesh has {vertices[i].shape[0]} vertices, the ground "
                                 f"truth {gt.vertices.shape[0]}: not the hand model of the capture")
            out.append(FitError(vertex_mm=float(np.linalg.norm(vertices[i] - gt.vertices, axis=1).mean() * 1000),
                                keypoint_mm=float(np.linalg.norm(keypoints[i] - gt.keypoints_3d, axis=1).mean()
                                                  * 1000)))
        return out

    def keypoint_error_mm(self, sample_id: int, keypoints_m: Sequence[Sequence[float]]) -> float:
        """Mean 3D distance of (21, 3) keypoints (e.g. MVNet's) from the truth, millimetres."""
        gt = self.truth(sample_id)
        return float(np.linalg.norm(np.asarray(keypoints_m, np.float64) - gt.keypoints_3d, axis=1).mean() * 1000)
