"""A simulated annotator: takes tasks from the annotator queue through the API and clicks wrist and
fingertips where the ground truth projects them, with the mistakes people make.

- clicks: the true 2D keypoint plus Gaussian noise of `click_sigma_px` per coordinate;
- occluded points (not visible in the ground truth): skipped (`not_annotated`), or, with
  `skip_occluded=False`, clicked at a best guess and marked `occluded`; points outside the image: skipped;
- finger swaps: with `swap_probability` per view, the clicks of two fingertips are exchanged;
- a sample sent back by a reviewer (it had an annotation pass already) gets all 21 keypoints clicked when
  `reannotate_all_keypoints` (the paper's "annotating" of samples that failed verification), else the
  sparse set again;
- masks: a view whose shown mask overlaps the true hand mask with IoU < `mask_iou_threshold` is corrected
  (at most `max_mask_corrections` per sample, worst first) to the true hand mask with a boundary displaced
  by smooth noise of `boundary_noise_px`.
- proposals (`accept_proposals_within_px`, off by default): the annotator accepts the page's proposal of a
  keypoint where it lies within that distance of the true point, instead of clicking it; one key per view
  (`UnitCosts.proposal_view_s`). The proposal is the page's first (annotation.js `proposals()`): the point
  triangulated from this pass's hand-placed clicks in the views done before (once placed by hand in 2 views,
  swapped clicks included; never from accepted points; projected inside the image: page_triangulation.py),
  else the first server source holding it inside the image, in the server's order (a source with per-keypoint
  confidences, MVNet's or the detector's, from confidence 0.3). As annotate.js, a point placed by hand moves
  the points accepted for that keypoint in the earlier views to the new triangulation. Points the annotator
  would skip stay skipped.
Time is counted with the unit costs (clicks, mask corrections, accepted views) and sent as `time_spent_s`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np

from backend.services.captures.masks import encode_rle as encode
from backend.simulation.client import ApiClient
from backend.simulation.costs import HumanLedger
from backend.simulation.page_triangulation import inside, project_point, triangulate_clicked, triangulated_proposal
from backend.simulation.truth import GroundTruthIndex

log = logging.getLogger(__name__)

FINGERTIPS = (4, 8, 12, 16, 20)
MIN_PROPOSAL_CONFIDENCE = 0.3  # a scored source's proposals are offered from this confidence (annotation.js)


def offered_proposals(proposals: dict) -> dict[tuple[int, int], tuple[float, float]]:
    """(view id, keypoint) -> the proposal the annotate page shows first, from the server's sources in order."""
    out: dict[tuple[int, int], tuple[float, float]] = {}
    cameras = {c["view_id"]: c for c in proposals.get("cameras", [])}
    for source in proposals.get("sources", []):
        confidences = source.get("confidences")
        for view_id, points in source.get("views", {}).items():
            cam = cameras.get(int(view_id))
            for k, point in enumerate(points):
                if point is None or (int(view_id), k) in out:
                    continue
                if cam is not None and not inside(point, cam):  # the page passes such a point over
                    continue
                # as annotation.js: any source with per-keypoint confidences (MVNet, the detector) from the minimum
                if confidences and confidences[k] is not None and confidences[k] < MIN_PROPOSAL_CONFIDENCE:
                    continue
                out[(int(view_id), k)] = (float(point[0]), float(point[1]))
    return out


@dataclass(frozen=True)
class AnnotatorConfig:
    """How a simulated annotator works (pixels; probabilities in [0, 1])."""

    click_sigma_px: float = 2.0
    swap_probability: float = 0.05
    skip_occluded: bool = True
    mask_iou_threshold: float = 0.5
    max_mask_corrections: int = 2
    boundary_noise_px: float = 1.5
    reannotate_all_keypoints: bool = True
    accept_proposals_within_px: float | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        tolerance = self.accept_proposals_within_px
        if tolerance is not None and not (math.isfinite(tolerance) and 0 <= tolerance <= 100):
            raise ValueError(f"accept_proposals_within_px must be in [0, 100] pixels or None, not {tolerance}")
        for name in ("click_sigma_px", "boundary_noise_px"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0 <= value <= 100):
                raise ValueError(f"{name} must be in [0, 100] pixels, not {value}")
        for name in ("swap_probability", "mask_iou_threshold"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0 <= value <= 1):
                raise ValueError(f"{name} must be in [0, 1], not {value}")
        if not 0 <= self.max_mask_corrections <= 64:
            raise ValueError(f"max_mask_corrections must be in 0..64, not {self.max_mask_corrections}")


@dataclass(frozen=True)
class AnnotationOutcome:
    """One submission: counts of what was done and the human seconds it cost."""

    sample_id: int
    clicks: int
    skipped_points: int
    swapped_views: int
    mask_corrections: int
    seconds: float
    fit_job_id: int | None


def iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def noisy_mask(mask: np.ndarray, noise_px: float, rng: np.random.Generator, smoothness_px: float = 4.0) -> np.ndarray:
    """The mask with its boundary moved in and out by smooth noise (std `noise_px`, correlation length about
    `smoothness_px`): the signed distance to the boundary plus a smooth random field, thresholded at 0."""
    mask = np.asarray(mask, bool)
    if noise_px <= 0 or not mask.any():
        return mask.copy()
    inside = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 3)
    outside = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 3)
    field = cv2.GaussianBlur(rng.normal(size=mask.shape).astype(np.float32), (0, 0), smoothness_px)
    field /= field.std() + 1e-9
    return (inside - outside + noise_px * field) > 0


def encode_rle(mask: np.ndarray) -> list[int]:
    """Row-major run lengths starting with background (the API's mask encoding, docs/api.md)."""

    return encode(mask)


class SimulatedAnnotator:
    """One annotator account working through the API."""

    def __init__(self, name: str, client: ApiClient, truth: GroundTruthIndex, ledger: HumanLedger,
                 config: AnnotatorConfig | None = None) -> None:
        self.name = name
        self.client = client
        self.truth = truth
        self.ledger = ledger
        self.config = config or AnnotatorConfig()
        self.rng = np.random.default_rng([self.config.seed, *name.encode()])
        self._submissions = 0

    def _shown_mask(self, view: dict) -> np.ndarray:
        if view.get("mask_url") is None:
            return np.zeros((view["height"], view["width"]), bool)
        data = np.frombuffer(self.client.file(view["mask_url"]), np.uint8)
        mask = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)
        if mask is None or mask.shape != (view["height"], view["width"]):
            raise ValueError(f"view {view['id']}: the served mask is unreadable or of the wrong size")
        return mask >= 128

    @staticmethod
    def _reproject_accepted(keypoint: int, clicked: list[tuple[dict, tuple[float, float]]], view_id: int,
                            placed: dict[int, dict[int, tuple[float, float, str]]], accepted_in: dict[int, set[int]],
                            page_cams: dict[int, dict]) -> None:
        """As annotate.js `reprojections`: a point placed by hand moves the proposals accepted for this keypoint
        in the other views to the new triangulation's projection (where it lies inside the image)."""
        tri = triangulate_clicked(clicked)
        if tri is None:
            return
        for other, taken in accepted_in.items():
            cam = page_cams.get(other)
            if other == view_id or keypoint not in taken or cam is None:
                continue
            p = project_point(tri.point, cam)
            if inside(p, cam):
                placed[other][keypoint] = (float(p[0]), float(p[1]), placed[other][keypoint][2])

    def annotate_next(self, round_index: int, give_up_on: frozenset[int] = frozenset(),
                      annotated_before: frozenset[int] = frozenset()) -> AnnotationOutcome | None:
        """Take the next annotation task and submit clicks (and mask corrections); None when the queue is
        empty, or when the task is a sample in `give_up_on` (its lease is released). Samples in
        `annotated_before` were sent back after an earlier pass."""
        task = self.client.next_annotation()
        if task is None:
            return None
        if task["sample_id"] in give_up_on:
            self.client.release_annotation(task["sample_id"], task["lease_token"])
            log.warning("%s: sample %d is back again; leaving it", self.name, task["sample_id"])
            return None
        cfg = self.config
        gt = self.truth.truth(task["sample_id"])
        cameras = list(gt.camera_names)
        tolerance = cfg.accept_proposals_within_px
        payload = self.client.proposals(task["sample_id"]) if tolerance is not None else {}
        offered = offered_proposals(payload)
        page_cams = {c["view_id"]: c for c in payload.get("cameras", [])}
        skipped, swapped, accepted, proposal_views, triangulated = 0, 0, 0, 0, 0
        keypoints = list(task["keypoints_to_click"])
        if cfg.reannotate_all_keypoints and task["sample_id"] in annotated_before:
            keypoints = list(range(gt.keypoints_2d.shape[1]))
        placed: dict[int, dict[int, tuple[float, float, str]]] = {}  # view id -> keypoint -> (x, y, visibility)
        accepted_in: dict[int, set[int]] = {}  # view id -> keypoints set from a proposal
        hand: dict[int, list[tuple[dict, tuple[float, float]]]] = {k: [] for k in keypoints}  # placed by hand
        for view in task["views"]:
            c = cameras.index(view["camera"])
            cam = page_cams.get(view["id"])
            points: dict[int, tuple[float, float, str]] = {}
            taken: set[int] = set()  # keypoints set from a proposal in this view
            for k in keypoints:
                x, y = gt.keypoints_2d[c, k]
                inside_image = -0.5 <= x <= view["width"] - 0.5 and -0.5 <= y <= view["height"] - 0.5
                if not inside_image or (not gt.visibility[c, k] and cfg.skip_occluded):
                    skipped += 1
                    continue
                # As annotation.js: first the point triangulated from this pass's hand-placed clicks, else the
                # server's first source.
                proposal = triangulated_proposal(hand[k], cam) if cam is not None else None
                from_triangulation = proposal is not None
                if proposal is None:
                    proposal = offered.get((view["id"], k))
                if proposal is not None and math.hypot(proposal[0] - x, proposal[1] - y) <= tolerance:
                    points[k] = (*proposal, "visible" if gt.visibility[c, k] else "occluded")
                    taken.add(k)
                    triangulated += from_triangulation
                    continue
                x, y = np.array([x, y]) + self.rng.normal(0, cfg.click_sigma_px, 2)
                x = float(np.clip(x, -0.5, view["width"] - 0.5))
                y = float(np.clip(y, -0.5, view["height"] - 0.5))
                points[k] = (x, y, "visible" if gt.visibility[c, k] else "occluded")
            accepted += len(taken)
            proposal_views += bool(taken)
            tips = [k for k in FINGERTIPS if k in points and k not in taken]  # a swap is a clicking mistake
            if len(tips) >= 2 and self.rng.random() < cfg.swap_probability:
                a, b = self.rng.choice(tips, 2, replace=False)
                (xa, ya, va), (xb, yb, vb) = points[a], points[b]
                points[a], points[b] = (xb, yb, va), (xa, ya, vb)
                swapped += 1
            placed[view["id"]], accepted_in[view["id"]] = points, taken
            if cam is not None:
                for k in points.keys() - taken:  # what was placed by hand (swaps included) triangulates later
                    hand[k].append((cam, points[k][:2]))
                    self._reproject_accepted(k, hand[k], view["id"], placed, accepted_in, page_cams)
        clicks = []
        for view in task["views"]:
            points, taken = placed[view["id"]], accepted_in[view["id"]]
            for k in keypoints:
                if k in points:
                    x, y, visibility = points[k]
                    clicks.append({"view_id": view["id"], "keypoint": k, "x": x, "y": y, "visibility": visibility,
                                   "from_proposal": k in taken})  # the fit weighs accepted proposals as such
                else:
                    clicks.append({"view_id": view["id"], "keypoint": k, "visibility": "not_annotated"})
        masks = []
        if cfg.max_mask_corrections and gt.hand_masks:
            scored = []
            for view in task["views"]:
                true_mask = gt.hand_masks[view["camera"]]
                overlap = iou(self._shown_mask(view), true_mask)
                if overlap < cfg.mask_iou_threshold and true_mask.any():
                    scored.append((overlap, view, true_mask))
            for _, view, true_mask in sorted(scored, key=lambda s: s[0])[:cfg.max_mask_corrections]:
                corrected = noisy_mask(true_mask, cfg.boundary_noise_px, self.rng)
                masks.append({"view_id": view["id"], "width": view["width"], "height": view["height"],
                              "rle": encode_rle(corrected)})
        n_clicks = sum(1 for c in clicks if c["visibility"] != "not_annotated") - accepted
        costs = self.ledger.costs
        seconds = (n_clicks * costs.click_s + len(masks) * costs.mask_correction_s
                   + proposal_views * costs.proposal_view_s)
        self._submissions += 1
        body = {"submission_id": f"sim-{self.name}-{task['sample_id']}-{self._submissions}",
                "lease_token": task["lease_token"], "time_spent_s": seconds, "clicks": clicks, "masks": masks}
        result = self.client.submit(task["sample_id"], body)
        self.ledger.add(round_index, clicks=n_clicks, skipped_points=skipped, swapped_views=swapped,
                        mask_corrections=len(masks), submissions=1, accepted_proposals=accepted,
                        proposal_views=proposal_views, accepted_triangulated=triangulated)
        return AnnotationOutcome(sample_id=task["sample_id"], clicks=n_clicks, skipped_points=skipped,
                                 swapped_views=swapped, mask_corrections=len(masks), seconds=seconds,
                                 fit_job_id=result.get("fit_job_id"))
