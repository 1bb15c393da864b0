"""Do the confidences mean something? Reliability of each confidence against the error it should predict, per round
(issue 15): the detector's per-view keypoint scores against their 2D error (pixels), the triangulation's
per-keypoint confidence against the lifted keypoint's 3D error (mm), MVNet's per-keypoint confidence against its
3D error (mm). Binned by confidence: the mean error per bin should fall as confidence rises.

The reference is the frame's ground truth where the capture has one (synthetic), else the sample's accepted fit
(what a reviewer verified); the answer counts each. Reads only.
"""

from __future__ import annotations

import io
import logging
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.capture import Sample
from backend.models.enums import SampleState
from backend.models.fits import Fit, Prediction
from backend.models.review import Round
from backend.services.captures.storage import Storage
from backend.services.display.view_geometry import view_cameras
from workers.geometry.projection import project_visible

log = logging.getLogger(__name__)

SOURCES = {"detector": "px", "triangulation": "mm", "mvnet": "mm"}
MAX_BINS = 50


def reliability_bins(confidence: np.ndarray, error: np.ndarray, bins: int) -> dict[str, Any]:
    """Equal-width confidence bins over [0, 1]: per bin the count and the mean error (None where empty).

    Args:
        confidence: (N,) in [0, 1] (values outside are clipped; non-finite pairs are dropped).
        error: (N,) the true error of each, in the source's unit.
        bins: number of bins, 1 ... MAX_BINS.
    """
    if not 1 <= bins <= MAX_BINS:
        raise ValueError(f"bins must be in 1..{MAX_BINS}, not {bins}")
    c = np.asarray(confidence, dtype=np.float64).ravel()
    e = np.asarray(error, dtype=np.float64).ravel()
    if c.shape != e.shape:
        raise ValueError(f"confidence {c.shape} and error {e.shape} differ in length")
    keep = np.isfinite(c) & np.isfinite(e)
    c, e = np.clip(c[keep], 0.0, 1.0), e[keep]
    edges = np.linspace(0.0, 1.0, bins + 1)
    index = np.minimum((c * bins).astype(int), bins - 1)
    counts = np.bincount(index, minlength=bins)
    sums = np.bincount(index, weights=e, minlength=bins)
    means = [round(float(s / n), 3) if n else None for s, n in zip(sums, counts, strict=True)]
    return {"edges": [round(float(x), 6) for x in edges], "counts": counts.tolist(), "mean_error": means,
            "n": int(counts.sum())}


@dataclass
class _Pairs:
    confidence: list[np.ndarray] = field(default_factory=list)
    error: list[np.ndarray] = field(default_factory=list)

    def add(self, confidence: np.ndarray, error: np.ndarray) -> None:
        self.confidence.append(np.ravel(confidence))
        self.error.append(np.ravel(error))

    def binned(self, bins: int) -> dict[str, Any]:
        if not self.confidence:
            return reliability_bins(np.zeros(0), np.zeros(0), bins)
        return reliability_bins(np.concatenate(self.confidence), np.concatenate(self.error), bins)


class _References:
    """Per sample the reference keypoints: (21, 3) metres world, and (C, 21, 2) px per view id when known."""

    def __init__(self, session: Session, storage: Storage) -> None:
        self.session, self.storage = session, storage
        self.cache: dict[int, tuple[str, np.ndarray, dict[int, np.ndarray]] | None] = {}
        self.used = {"ground_truth": set(), "accepted_fit": set()}

    def of(self, sample_id: int) -> tuple[str, np.ndarray, dict[int, np.ndarray]] | None:
        if sample_id not in self.cache:
            self.cache[sample_id] = self._load(sample_id)
        found = self.cache[sample_id]
        if found is not None:
            self.used[found[0]].add(sample_id)
        return found

    def _load(self, sample_id: int) -> tuple[str, np.ndarray, dict[int, np.ndarray]] | None:
        sample = self.session.get(Sample, sample_id)
        if sample is None:
            return None
        cameras = view_cameras(self.session, sample_id)
        if sample.ground_truth_key:
            try:
                with np.load(io.BytesIO(self.storage.get_bytes(sample.ground_truth_key)), allow_pickle=False) as npz:
                    points = np.asarray(npz["keypoints_3d"], np.float64).reshape(21, 3)
                    pixels = np.asarray(npz["keypoints_2d"], np.float64)
                    names = [str(n) for n in npz["camera_names"]]
                by_view = {cam.view_id: pixels[names.index(cam.name)] for cam in cameras if cam.name in names}
                return "ground_truth", points, by_view
            except (OSError, KeyError, ValueError, AttributeError) as exc:
                log.warning("sample %s: ground truth unreadable (%s); using its accepted fit if any", sample_id, exc)
        if sample.state == SampleState.accepted and sample.current_fit_id is not None:
            fit = self.session.get(Fit, sample.current_fit_id)
            points = np.asarray(fit.keypoints_m, np.float64).reshape(21, 3)
            return "accepted_fit", points, {cam.view_id: project_visible(points, cam) for cam in cameras}
        return None


def _round_indices(session: Session) -> dict[int | None, int]:
    out: dict[int | None, int] = {rid: index for rid, index in session.execute(select(Round.id, Round.index))}
    out[None] = 0  # recorded before any round was open: round 0
    return out


def _detector_pairs(detection: dict[str, Any], reference: tuple[str, np.ndarray, dict[int, np.ndarray]],
                    detector: _Pairs, triangulation: _Pairs) -> None:
    _, points, by_view = reference
    lifted = np.array(detection.get("points_world"), dtype=np.float64).reshape(21, 3)
    confidence = np.array(detection.get("confidence"), dtype=np.float64).reshape(21)
    triangulation.add(confidence, 1000.0 * np.linalg.norm(lifted - points, axis=1))
    for view_id, view in zip(detection.get("view_ids", []), detection.get("views", []), strict=False):
        if view is None or int(view_id) not in by_view:
            continue
        xy = np.array(view.get("keypoints_px"), dtype=np.float64).reshape(21, 2)
        scores = np.array(view.get("scores"), dtype=np.float64).reshape(21)
        detector.add(scores, np.linalg.norm(xy - by_view[int(view_id)], axis=1))


def reliability(session: Session, storage: Storage, *, bins: int = 10) -> dict[str, Any]:
    """Per round index and source (`SOURCES`): the binned reliability; the references used."""
    if not 1 <= bins <= MAX_BINS:
        raise ValueError(f"bins must be in 1..{MAX_BINS}, not {bins}")
    rounds = _round_indices(session)
    refs = _References(session, storage)
    pairs: dict[int, dict[str, _Pairs]] = {}

    def of_round(index: int) -> dict[str, _Pairs]:
        return pairs.setdefault(index, {name: _Pairs() for name in SOURCES})

    fits: Iterable[Fit] = session.execute(select(Fit).order_by(Fit.id)).scalars()
    for fit in fits:
        detection = (fit.inputs or {}).get("detection") if (fit.inputs or {}).get("source") == "detector" else None
        if not isinstance(detection, dict) or (reference := refs.of(fit.sample_id)) is None:
            continue
        row = of_round(rounds.get(fit.round_id, 0))
        try:
            _detector_pairs(detection, reference, row["detector"], row["triangulation"])
        except (TypeError, ValueError) as exc:  # a stored record this code cannot read: left out, said in the log
            log.warning("fit %s: detection left out of the reliability (%s)", fit.id, exc)
    for prediction in session.execute(select(Prediction).order_by(Prediction.id)).scalars():
        if (reference := refs.of(prediction.sample_id)) is None:
            continue
        error = 1000.0 * np.linalg.norm(np.asarray(prediction.keypoints_m, np.float64) - reference[1], axis=1)
        of_round(rounds.get(prediction.round_id, 0))["mvnet"].add(np.asarray(prediction.confidences, np.float64),
                                                                   error)
    return {"bins": bins, "units": dict(SOURCES),
            "references": {k: len(v) for k, v in refs.used.items()},
            "rounds": [{"index": index, "sources": {name: p.binned(bins) for name, p in sources.items()}}
                       for index, sources in sorted(pairs.items())]}
