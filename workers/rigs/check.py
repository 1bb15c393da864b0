"""The calibration check: do the cameras agree about where 2D keypoints are? (`handloop calibration check`)

From 2D keypoints of the same hand in several views, found WITHOUT the calibration under test (ground truth in
synthetic captures, the detector's keypoints per view otherwise, annotators' clicks on the admin page):
- per camera pair, the symmetric epipolar distances (pixels, after undistortion) under the calibration, and
  under the best relative pose any calibration could give those keypoints (refit from the calibration's, the
  intrinsics kept): the pair's yardstick. The pair's *excess* is what the calibration adds over it,
  sqrt(rms^2 - best^2) of the trimmed RMS (the largest 20 % of distances left out: outlier keypoints and views);
  a pair disagrees when its excess exceeds its limit, max(floor, best x sqrt(PAIR_RATIO^2 - 1));
- per camera, the excess over all its pairs that a correction of its pose alone removes (CAMERA_RATIO).
The verdict explains the disagreements consistently: a camera is blamed when removing it leaves pairs that all
agree and it disagrees itself; among several such cameras the one whose correction removes the most. Then the
blamed camera's pairs are refitted with a rotation alone and a move alone (a turned camera, a stale extrinsic).
When no single camera explains it, exchanging two cameras' calibrations is tried (swapped names); otherwise the
rig "disagrees in several places". Two cameras: only the pair is judged (consistent or not, no blame).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.epipolar import fundamental_matrix, signed_symmetric_distances
from workers.handmodel.keypoints import NUM_KEYPOINTS
from workers.rigs.epipolar import corrected, fit_correction, refit_pair, trimmed_rms
from workers.rigs.hand_scale import HandScale, estimate_hand_scale, triangulate_keypoints

FLOOR_FRACTION = 0.003  # an excess below this fraction of the image width (4 px at 1280 px) is never a finding
FLOOR_MIN_PX = 2.0
PAIR_RATIO = 1.2  # a pair disagrees when the calibration's trimmed RMS exceeds the best pose's by this factor
CAMERA_RATIO = 1.04  # a camera disagrees when correcting its pose lowers its pairs' trimmed RMS by this factor
MIN_PAIR_POINTS = 6  # keypoints two cameras must share for the pair to be judged (sparse clicks: a few a sample)
REFIT_MIN_POINTS = 12  # ... and for its own best-pose yardstick; fewer borrow the median of the others' yardsticks
MIN_PARTNERS = 2  # judged pairs a camera needs to be judged (one pair cannot say which camera is off)
CLOSE_CALL = 0.9  # two cameras explain it about equally when the runner-up's evidence is this close
SWAP_CANDIDATES = 4  # the swap test exchanges the calibrations of the cameras with the most evidence
DETECTOR_MIN_SCORE = 0.5


class CheckError(ValueError):
    """The check cannot run (no keypoints source, too few cameras); the message says why."""


@dataclass(frozen=True)
class PairFigure:
    """Epipolar agreement of two cameras over `points` shared keypoints, pixels: the median and 90th percentile
    distance, the trimmed RMS under the calibration and under the best relative pose, the excess the calibration
    adds and the limit it is judged by (NaN where the pair is not judged)."""

    a: str
    b: str
    median_px: float
    p90_px: float
    points: int
    rms_px: float
    best_px: float
    excess_px: float
    limit_px: float
    judged: bool
    consistent: bool


@dataclass(frozen=True)
class CameraFigure:
    """One camera, pixels: the median over its judged partners of their pairs' median distance, the excess a
    correction of its pose removes from its pairs and the limit judged by, the keypoints it shares with any other
    camera, how many partners it is judged against, the verdict, the reason, and the fitted correction."""

    name: str
    epipolar_px: float
    excess_px: float
    threshold_px: float
    points: int
    partners: int
    judged: bool
    flagged: bool
    reason: str = ""
    correction: dict[str, Any] | None = None


@dataclass
class CheckReport:
    """The check's figures. `verdict`: consistent | camera | swapped | ambiguous | several (three or more
    cameras), pair-consistent | pair-inconsistent (two), not-judged; `summary` says it in a sentence."""

    source: str
    frames: int
    cameras: list[CameraFigure]
    pairs: list[PairFigure]
    verdict: str = "not-judged"
    summary: str = ""
    notes: list[str] = field(default_factory=list)
    hand_scale: HandScale | None = None  # the rig's scale judged by the triangulated hand's size (21 keypoints)

    @property
    def flagged(self) -> list[str]:
        return [c.name for c in self.cameras if c.flagged]

    @property
    def scale_wrong(self) -> bool:
        """True when the triangulated hand is of no human size: the calibration's length unit is wrong."""
        return self.hand_scale is not None and self.hand_scale.verdict in ("too large", "too small")

    @property
    def agrees(self) -> bool:
        """True when the calibration agrees with the keypoints (or nothing could be judged) and its scale does."""
        return self.verdict in ("consistent", "pair-consistent", "not-judged") and not self.scale_wrong

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON types; figures that could not be computed (NaN) are None."""
        def clean(value: Any) -> Any:
            if isinstance(value, float | np.floating):
                return float(value) if np.isfinite(value) else None
            if isinstance(value, dict):
                return {k: clean(v) for k, v in value.items()}
            if isinstance(value, list | tuple):
                return [clean(v) for v in value]
            if isinstance(value, np.integer | np.bool_):
                return value.item()
            return value

        return clean({"source": self.source, "frames": self.frames, "verdict": self.verdict,
                      "summary": self.summary, "flagged": self.flagged,
                      "cameras": [asdict(c) for c in self.cameras], "pairs": [asdict(p) for p in self.pairs],
                      "hand_scale": None if self.hand_scale is None else {
                          **asdict(self.hand_scale), "scale_wrong": self.scale_wrong,
                          "message": self.hand_scale.message()},
                      "notes": list(self.notes)})


def _px(value: float) -> str:
    """A pixel figure for a message: never 'nan'."""
    return f"{value:.1f} px" if np.isfinite(value) else "n/a"


@dataclass
class _Pair:
    """One pair's keypoints (undistorted, camera a then b) and its yardstick."""

    a: int
    b: int
    xa: np.ndarray
    xb: np.ndarray
    raw_a: np.ndarray  # the same keypoints as distorted pixels (the swap test undistorts them again)
    raw_b: np.ndarray
    best: float  # trimmed RMS under the refitted relative pose
    limit: float

    def excess(self, d: np.ndarray) -> float:
        return float(np.sqrt(max(0.0, trimmed_rms(d) ** 2 - self.best ** 2)))


def _undistorted(keypoints_px: list[np.ndarray], visible: list[np.ndarray], cameras: list[Camera]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(C, N, 2) distorted and undistorted pixels of every frame's keypoints, NaN where not visible."""
    from workers.geometry.projection import undistort_pixels  # deferred: torch; the API imports this module

    C = len(cameras)
    if not keypoints_px:
        return np.zeros((C, 0, 2)), np.zeros((C, 0, 2))
    kp = np.concatenate([np.where(np.asarray(v, bool)[..., None], np.asarray(k, np.float64), np.nan)
                         for k, v in zip(keypoints_px, visible, strict=True)], axis=1)
    out = np.full_like(kp, np.nan)
    for c, cam in enumerate(cameras):
        ok = np.isfinite(kp[c]).all(axis=1)
        if ok.any():
            out[c, ok] = undistort_pixels(kp[c, ok], cam)
    return kp, out


def _pair_distances(cameras: list[Camera], pair: _Pair) -> np.ndarray:
    return signed_symmetric_distances(fundamental_matrix(cameras[pair.a], cameras[pair.b]), pair.xa, pair.xb)


def check_keypoints(cameras: list[Camera], keypoints_px: list[np.ndarray], visible: list[np.ndarray], *,
                    source: str = "keypoints", notes: list[str] | None = None) -> CheckReport:
    """The check from per-frame 2D keypoints.

    Args:
        cameras: the C >= 2 cameras of the calibration under test.
        keypoints_px: per frame (C, K, 2) distorted pixels (NaN where not seen).
        visible: per frame (C, K) bool, the keypoints to use.
        source: where the keypoints came from, for the report.
    Returns:
        The report. Two cameras: only the pair is judged.
    Raises:
        CheckError: fewer than two cameras.
    """
    C = len(cameras)
    if C < 2:
        raise CheckError(f"the check compares cameras with each other: it needs at least 2, the rig has {C}")
    notes = list(notes or [])
    raw, U = _undistorted(keypoints_px, visible, cameras)
    ok = np.isfinite(U).all(axis=2)
    floors = np.array([max(FLOOR_MIN_PX, FLOOR_FRACTION * cam.width) for cam in cameras])
    names = [cam.name for cam in cameras]
    figures: list[PairFigure] = []
    pairs: dict[tuple[int, int], _Pair] = {}
    for a, b in combinations(range(C), 2):
        both = ok[a] & ok[b]
        n = int(both.sum())
        xa, xb = U[a, both], U[b, both]
        d = np.abs(signed_symmetric_distances(fundamental_matrix(cameras[a], cameras[b]), xa, xb)) if n else np.zeros(0)
        median, p90 = (float(np.median(d)), float(np.quantile(d, 0.9))) if n else (float("nan"), float("nan"))
        if n < MIN_PAIR_POINTS:
            figures.append(PairFigure(cameras[a].name, cameras[b].name, median, p90, n, float("nan"), float("nan"),
                                      float("nan"), float("nan"), False, True))
            continue
        best = trimmed_rms(refit_pair(cameras[a], cameras[b], xa, xb)) if n >= REFIT_MIN_POINTS else float("nan")
        pairs[(a, b)] = _Pair(a, b, xa, xb, raw[a, both], raw[b, both], best, float("nan"))
        figures.append(PairFigure(cameras[a].name, cameras[b].name, median, p90, n, trimmed_rms(d), best,
                                  float("nan"), float("nan"), True, True))
    own = [p.best for p in pairs.values() if np.isfinite(p.best)]
    borrowed = float(np.median(own)) if own else 0.0
    for k, figure in enumerate(figures):
        key = (names.index(figure.a), names.index(figure.b))
        if key not in pairs:
            continue
        pair = pairs[key]
        pair.best = pair.best if np.isfinite(pair.best) else borrowed
        pair.limit = max(floors[pair.a], floors[pair.b], pair.best * np.sqrt(PAIR_RATIO ** 2 - 1))
        excess = pair.excess(_pair_distances(cameras, pair))
        figures[k] = replace(figure, best_px=pair.best, excess_px=excess, limit_px=pair.limit,
                             consistent=excess <= pair.limit)
    by_key = {(f.a, f.b): f for f in figures}
    medians = {key: by_key[(cameras[key[0]].name, cameras[key[1]].name)].median_px for key in pairs}
    bad_pairs = {key for key in pairs if not by_key[(cameras[key[0]].name, cameras[key[1]].name)].consistent}
    shared = [int((ok[c] & (ok.sum(axis=0) >= 2)).sum()) for c in range(C)]
    report = CheckReport(source=source, frames=len(keypoints_px), cameras=[], pairs=figures, notes=notes,
                         hand_scale=_hand_scale(cameras, keypoints_px, visible))
    if C == 2:
        return _judge_pair(report, cameras, pairs, shared)
    return _judge_rig(report, cameras, pairs, bad_pairs, medians, shared, floors)


def _hand_scale(cameras: list[Camera], keypoints_px: list[np.ndarray], visible: list[np.ndarray]) -> HandScale | None:
    """The hand's size as the calibration triangulates it (plain DLT of the visible keypoints, no metric threshold),
    judged against adult hands; None when the keypoints are not a hand's 21."""
    if not keypoints_px or np.shape(keypoints_px[0])[1:] != (NUM_KEYPOINTS, 2):
        return None
    pixels = np.stack([np.where(np.asarray(vis, bool)[..., None], np.asarray(kp, np.float64), np.nan)
                       for kp, vis in zip(keypoints_px, visible, strict=True)], axis=1)  # (C, N, 21, 2)
    return estimate_hand_scale(triangulate_keypoints(pixels, cameras))


def _judge_pair(report: CheckReport, cameras: list[Camera], pairs: dict[tuple[int, int], _Pair],
                shared: list[int]) -> CheckReport:
    a, b = cameras[0].name, cameras[1].name
    figure = report.pairs[0]
    why = "two cameras: only the pair's agreement is judged, not which camera is off"
    report.cameras = [CameraFigure(cam.name, figure.median_px, figure.excess_px, figure.limit_px, shared[c],
                                   1 if pairs else 0, False, False, why) for c, cam in enumerate(cameras)]
    if not pairs:
        report.verdict = "not-judged"
        report.summary = (f"the pair {a}-{b} shares only {figure.points} keypoints (needs {MIN_PAIR_POINTS}): "
                          "not judged")
    elif figure.consistent:
        report.verdict = "pair-consistent"
        report.summary = (f"the pair {a}-{b} agrees: median {_px(figure.median_px)}, excess over the best pose "
                          f"{_px(figure.excess_px)} (limit {_px(figure.limit_px)}); {why}")
    else:
        report.verdict = "pair-inconsistent"
        report.summary = (f"the pair {a}-{b} disagrees: median {_px(figure.median_px)}, the calibration adds "
                          f"{_px(figure.excess_px)} over the best pose (limit {_px(figure.limit_px)}); {why}")
    return report


def _judge_rig(report: CheckReport, cameras: list[Camera], pairs: dict[tuple[int, int], _Pair],
               bad_pairs: set[tuple[int, int]], medians: dict[tuple[int, int], float], shared: list[int],
               floors: np.ndarray) -> CheckReport:
    C = len(cameras)
    partners = [[key for key in pairs if c in key] for c in range(C)]
    judged = [len(partners[c]) >= MIN_PARTNERS for c in range(C)]
    # Per camera: the excess a correction of its own pose removes from its pairs (pooled).
    evidence = np.zeros(C)
    strength = np.zeros(C)  # the excess a pose correction removes over what remains: ranks the explanations
    excess = np.full(C, np.nan)
    limit = np.full(C, np.nan)
    fitted: dict[int, tuple[np.ndarray, list[np.ndarray]]] = {}
    for c in range(C):
        if not judged[c]:
            continue
        x_self, x_other, others = _sides(c, partners[c], pairs, cameras)
        before = np.concatenate([_pair_distances(cameras, pairs[key]) for key in partners[c]])
        params, after = fit_correction(cameras[c], others, x_self, x_other, "pose")
        fitted[c] = (params, after)
        rms_after = trimmed_rms(np.concatenate(after))
        excess[c] = np.sqrt(max(0.0, trimmed_rms(before) ** 2 - rms_after ** 2))
        limit[c] = max(floors[c], rms_after * np.sqrt(CAMERA_RATIO ** 2 - 1))
        pair_evidence = max([pairs[k].excess(_pair_distances(cameras, pairs[k])) / pairs[k].limit
                             for k in partners[c]], default=0.0)
        evidence[c] = max(excess[c] / limit[c], pair_evidence)
        strength[c] = excess[c] / max(rms_after, 1e-9)
    suspects = [c for c in range(C) if judged[c] and evidence[c] > 1]
    explainers = [c for c in suspects if not any(key for key in bad_pairs if c not in key)]
    explainers.sort(key=lambda c: -strength[c])
    # A camera with too few partners to be judged explains a disagreement of its own pairs as well as they do.
    unjudged = [c for c in range(C) if not judged[c] and any(c in key for key in bad_pairs)
                and not any(c not in key for key in bad_pairs)]
    blamed: list[int] = []
    corrections: dict[int, dict[str, Any]] = {}
    diagnoses: dict[int, dict[str, Any]] = {}
    if len(explainers) > 1 and strength[explainers[1]] >= CLOSE_CALL * strength[explainers[0]]:
        # A close call: the camera whose rotation or move alone explains its pairs best (a partner's correction
        # that fixes the shared pair breaks its other pairs).
        diagnoses.update({c: _diagnose(c, cameras, pairs, partners[c], fitted[c][0]) for c in explainers})
        simple = {c: diagnoses[c]["score"] for c in explainers}
        fits_alone = [c for c in explainers if simple[c] <= 1]
        if len(fits_alone) == 1:
            explainers = fits_alone
        else:  # the most evidence wins; the runner-up is named
            first, second = explainers[:2]
            report.notes.append(f"camera {cameras[second].name!r} explains the disagreement nearly as well as "
                                f"{cameras[first].name!r} (its pose correction removes {strength[second]:.2f} against "
                                f"{strength[first]:.2f} of what remains)")
            explainers = explainers[:1]
    report.verdict = "several"  # until an explanation is found below
    if unjudged:
        names_all = ", ".join(cameras[c].name for c in explainers + unjudged)
        report.verdict = "ambiguous"
        report.summary = (f"the rig disagrees, and cameras {names_all} each explain it: "
                          f"{', '.join(cameras[c].name for c in unjudged)} has too few partner cameras to be judged "
                          "(more annotated samples or views would tell)")
    elif not suspects and not bad_pairs:
        report.verdict = "consistent" if pairs else "not-judged"
        report.summary = "no camera disagrees with the others" if pairs else (
            f"no two cameras share {MIN_PAIR_POINTS} keypoints: nothing could be judged")
    elif explainers and (len(explainers) == 1 or strength[explainers[1]] < CLOSE_CALL * strength[explainers[0]]):
        c = explainers[0]
        blamed = [c]
        corrections[c] = diagnoses.get(c) or _diagnose(c, cameras, pairs, partners[c], fitted[c][0])
        report.verdict = "camera"
        report.summary = f"camera {cameras[c].name!r} disagrees with the others: {corrections[c]['explanation']}"
    swap_now = report.verdict not in ("consistent", "ambiguous", "not-judged") and (
        not blamed or corrections[blamed[0]]["kind"] == "disagrees")
    if swap_now:
        # Swapped names look like one camera that no pose correction fixes (three cameras) or like two cameras
        # whose pairs alone disagree: exchange calibrations and look again.
        ranked = sorted(suspects, key=lambda c: -evidence[c])[:SWAP_CANDIDATES]
        two_sets = [(i, j) for i, j in combinations(range(C), 2) if all(set(k) & {i, j} for k in bad_pairs)]
        candidates = two_sets + [p for p in combinations(sorted(set(ranked + blamed)), 2) if p not in two_sets]
        swap = _swap_test(cameras, pairs, bad_pairs, candidates)
        if swap is not None:
            i, j = swap
            blamed = [i, j]
            text = (f"cameras {cameras[i].name!r} and {cameras[j].name!r} have each other's calibration (swapped "
                    "names): with their calibrations exchanged every pair agrees")
            corrections = {i: {"kind": "swapped", "with": cameras[j].name, "explanation": text},
                           j: {"kind": "swapped", "with": cameras[i].name, "explanation": text}}
            report.verdict = "swapped"
            report.summary = text
        elif not blamed:
            names = ", ".join(cameras[c].name for c in (explainers or suspects))
            if len(explainers) > 1:
                report.verdict = "ambiguous"
                report.summary = (f"the rig disagrees, and cameras {names} each explain it about equally well: which "
                                  "one is off cannot be told from these keypoints (more cameras or views would)")
            else:
                report.verdict = "several"
                bad = ", ".join(f"{cameras[a].name}-{cameras[b].name}" for a, b in sorted(bad_pairs))
                report.summary = (f"the rig disagrees in several places: no single camera explains it (pairs that "
                                  f"disagree: {bad or 'none alone'}; cameras whose pose correction helps: "
                                  f"{names or 'none'})")
    report.cameras = []
    for c, cam in enumerate(cameras):
        epi = [medians[key] for key in partners[c] if not set(key) & (set(blamed) - {c})]
        reason = f"camera {cam.name!r} disagrees with the others: {corrections[c]['explanation']}" \
            if c in corrections and report.verdict == "camera" else corrections[c]["explanation"] \
            if c in corrections else ""
        if not judged[c]:
            reason = _not_judged_reason(c, cameras, pairs, shared)
            report.notes.append(reason)
        report.cameras.append(CameraFigure(cam.name, float(np.median(epi)) if epi else float("nan"),
                                           float(excess[c]), float(limit[c]), shared[c], len(partners[c]),
                                           judged[c], c in blamed, reason, corrections.get(c)))
    return report


def _sides(c: int, keys: list[tuple[int, int]], pairs: dict[tuple[int, int], _Pair], cameras: list[Camera]
           ) -> tuple[list[np.ndarray], list[np.ndarray], list[Camera]]:
    """Camera c's pairs as (its keypoints, the partner's keypoints, the partner)."""
    x_self = [pairs[k].xa if k[0] == c else pairs[k].xb for k in keys]
    x_other = [pairs[k].xb if k[0] == c else pairs[k].xa for k in keys]
    return x_self, x_other, [cameras[k[1] if k[0] == c else k[0]] for k in keys]


def _not_judged_reason(c: int, cameras: list[Camera], pairs: dict[tuple[int, int], _Pair], shared: list[int]) -> str:
    name = cameras[c].name
    if shared[c] < MIN_PAIR_POINTS:
        return (f"camera {name!r}: not judged, too few keypoints: it shares {shared[c]} with other cameras "
                f"(needs {MIN_PAIR_POINTS} with each of {MIN_PARTNERS} partners)")
    n = sum(1 for key in pairs if c in key)
    return (f"camera {name!r}: not judged, too few partner cameras: it shares {MIN_PAIR_POINTS} or more keypoints "
            f"with {n} camera{'s' if n != 1 else ''} (needs {MIN_PARTNERS}: one pair cannot say which camera is off)")


def _diagnose(c: int, cameras: list[Camera], pairs: dict[tuple[int, int], _Pair], keys: list[tuple[int, int]],
              pose: np.ndarray) -> dict[str, Any]:
    """Which correction of camera c's pose explains its pairs: a rotation about its centre, a move of its centre,
    both, or none (intrinsics, distortion, a wrong image)."""
    x_self, x_other, others = _sides(c, keys, pairs, cameras)

    def score(after: list[np.ndarray]) -> float:
        return max(pairs[k].excess(d) / pairs[k].limit for k, d in zip(keys, after, strict=True))

    fits = {"rotation": fit_correction(cameras[c], others, x_self, x_other, "rotation"),
            "translation": fit_correction(cameras[c], others, x_self, x_other, "translation")}
    scores = {kind: score(after) for kind, (_, after) in fits.items()}
    pose_after = [signed_symmetric_distances(fundamental_matrix(corrected(cameras[c], pose, "pose"), o), xs, xo)
                  for o, xs, xo in zip(others, x_self, x_other, strict=True)]
    degrees = float(np.rad2deg(np.linalg.norm(fits["rotation"][0])))
    shift = float(np.linalg.norm(fits["translation"][0]))
    rotation = f"turned by {degrees:.1f} degrees (a rotation about its centre explains its pairs)"
    move = f"moved by {shift:.3g} calibration units (a move of its centre explains its pairs; stale extrinsics)"
    simplest = min(scores.values())
    if scores["rotation"] <= 1 and (scores["translation"] > 1 or scores["rotation"] <= scores["translation"]):
        return {"kind": "rotation", "degrees": degrees, "axis": _axis(fits["rotation"][0]), "explanation": rotation,
                "score": simplest}
    if scores["translation"] <= 1:
        return {"kind": "translation", "shift": fits["translation"][0].tolist(), "distance": shift,
                "explanation": move, "score": simplest}
    if score(pose_after) <= 1:
        pose_deg, pose_shift = float(np.rad2deg(np.linalg.norm(pose[:3]))), float(np.linalg.norm(pose[3:]))
        return {"kind": "pose", "degrees": pose_deg, "distance": pose_shift, "score": simplest,
                "explanation": f"its pose is off: turned by {pose_deg:.1f} degrees and moved by {pose_shift:.3g} "
                               "calibration units explain its pairs (stale or mis-converted extrinsics)"}
    return {"kind": "disagrees", "score": simplest,
            "explanation": "no correction of its pose explains its pairs: wrong intrinsics or "
                                                "distortion, a transposed or mis-converted pose, or another camera's "
                                                "images"}


def _axis(rvec: np.ndarray) -> list[float]:
    norm = float(np.linalg.norm(rvec))
    return (rvec / norm).round(3).tolist() if norm > 0 else [0.0, 0.0, 0.0]


def _swap_test(cameras: list[Camera], pairs: dict[tuple[int, int], _Pair], bad_pairs: set[tuple[int, int]],
               candidates: list[tuple[int, int]]) -> tuple[int, int] | None:
    """The first two cameras (of `candidates`) whose calibrations, exchanged, make every judged pair agree; None
    when none do. The pairs with either camera are undistorted and given their yardstick again."""
    from workers.geometry.projection import undistort_pixels  # deferred: torch

    floors = [max(FLOOR_MIN_PX, FLOOR_FRACTION * cam.width) for cam in cameras]
    for i, j in candidates:
        if any(not set(key) & {i, j} for key in bad_pairs):
            continue  # a pair without either camera disagrees: exchanging them cannot make every pair agree
        trial = list(cameras)
        trial[i], trial[j] = replace(cameras[j], name=cameras[i].name), replace(cameras[i], name=cameras[j].name)
        agree = True
        for pair in pairs.values():
            if not {pair.a, pair.b} & {i, j}:
                continue  # unchanged, and agreeing (a candidate leaves no disagreeing pair outside it)
            xa = undistort_pixels(pair.raw_a, trial[pair.a]) if pair.a in (i, j) else pair.xa
            xb = undistort_pixels(pair.raw_b, trial[pair.b]) if pair.b in (i, j) else pair.xb
            best = trimmed_rms(refit_pair(trial[pair.a], trial[pair.b], xa, xb))
            limit = max(floors[pair.a], floors[pair.b], best * np.sqrt(PAIR_RATIO ** 2 - 1))
            d = signed_symmetric_distances(fundamental_matrix(trial[pair.a], trial[pair.b]), xa, xb)
            if np.sqrt(max(0.0, trimmed_rms(d) ** 2 - best ** 2)) > limit:
                agree = False
                break
        if agree:
            return i, j
    return None


def _frames(capture: Any, sequence_id: str | None, max_frames: int) -> list[Any]:
    seqs = [capture.sequence(sequence_id)] if sequence_id else list(capture.sequences)
    frames = [f for s in seqs for f in s.frames]
    if len(frames) > max_frames:
        frames = [frames[i] for i in np.linspace(0, len(frames) - 1, max_frames).round().astype(int)]
    return frames


def detector_unavailable() -> str | None:
    """None when workers.detector can detect; else why not (module absent, or its own status)."""
    try:
        from workers.detector import detector_status  # deferred: loads the detector's pipeline (torch)

        return detector_status()
    except ImportError as exc:
        return f"the detector is not part of this build ({exc})"


def _box(mask: np.ndarray | None) -> list[float] | None:
    """x, y, w, h around a view's hand mask (a chroma key: no calibration), 20 % margin, inside the image."""
    if mask is None or not np.any(mask):
        return None
    ys, xs = np.nonzero(mask)
    h, w = mask.shape
    cx, cy = (xs.min() + xs.max() + 1) / 2, (ys.min() + ys.max() + 1) / 2
    side = 1.2 * max(xs.max() + 1 - xs.min(), ys.max() + 1 - ys.min())
    x0, y0 = max(0.0, cx - side / 2), max(0.0, cy - side / 2)
    return [x0, y0, min(float(w), cx + side / 2) - x0, min(float(h), cy + side / 2) - y0]


def check_capture(path: Path, *, source: str = "auto", sequence_id: str | None = None, max_frames: int = 50,
                  log: Callable[[str], None] | None = None, progress: bool = False) -> CheckReport:
    """Run the check on a capture folder.

    The detector's keypoints are found per view WITHOUT the calibration under test (the palm detector over the
    whole image, or around the view's hand mask, then the landmark model: `detect_image`), at the capture's
    working width, and mapped back to full-resolution pixels.

    Args:
        path: the capture.
        source: "ground-truth", "detector" or "auto" (ground truth when the capture has it, else the detector).
        sequence_id: only this sequence (default: all).
        max_frames: frames used, spread evenly.
        log: what the check decided before detecting, and fallback messages.
        progress: a progress bar of the detection on stderr.
    Raises:
        CheckError: fewer than two cameras, no usable keypoint source; CaptureError: the capture is malformed.
    """
    # deferred: the capture reader pulls in cv2 and PIL; the API imports this module for check_keypoints
    from workers.capture import load_frame_masks, load_ground_truth, read_capture
    from workers.capture.working import load_working_images, mask_to_working, to_full_px, working_cameras

    capture = read_capture(path, check_images=False)
    cameras = list(capture.cameras)
    if len(cameras) < 2:  # decided before any keypoint is read or detected
        raise CheckError(f"{path}: the check compares cameras with each other: it needs at least 2, the capture "
                         f"has {len(cameras)}")
    try:
        frames = _frames(capture, sequence_id, max_frames)
    except KeyError as exc:
        raise CheckError(str(exc.args[0])) from None
    small = list(working_cameras(cameras, capture.working_width_px))
    has_gt = bool(frames) and all(f.ground_truth_path is not None for f in frames)
    notes: list[str] = []
    if source == "auto":
        source = "ground-truth" if has_gt else "detector"
    if source == "ground-truth" and not has_gt:
        raise CheckError(f"{path}: the capture has no ground truth; use --keypoints detector")
    if source == "detector":
        why = detector_unavailable()
        if why is not None:
            raise CheckError(f"the detector cannot run: {why}. Without it the check needs 2D keypoints: ground truth "
                             "(synthetic captures) or annotators' clicks (after a round of annotation)")
    if log and len(cameras) == 2:
        log(f"check: two cameras ({cameras[0].name}, {cameras[1].name}): only the pair's agreement can be judged, "
            "not which camera is off")
    keypoints, visible = [], []
    if source == "ground-truth":
        for frame in frames:
            gt = load_ground_truth(frame)
            keypoints.append(gt.keypoints_2d)
            visible.append(gt.visibility)
        return check_keypoints(cameras, keypoints, visible, source=source, notes=notes)
    from tqdm import tqdm

    from workers.detector.pipeline import detect_image  # deferred: the pipeline (torch)
    from workers.detector.types import DetectorInputError

    with tqdm(total=len(frames) * len(cameras), unit="view", desc="check: detecting", file=sys.stderr,
              disable=not progress) as bar:
        for frame in frames:
            images = load_working_images(frame.image_paths, cameras, small)
            masks = load_frame_masks(frame)
            kp = np.full((len(cameras), 21, 2), np.nan)
            vis = np.zeros((len(cameras), 21), bool)
            for c, (cam, work) in enumerate(zip(cameras, small, strict=True)):
                box = _box(mask_to_working(masks[cam.name], work)) if cam.name in masks else None
                try:
                    view = detect_image(images[cam.name], box, handedness=capture.hand_model.side)
                except DetectorInputError as exc:
                    notes.append(f"{frame.sequence_id} frame {frame.index} {cam.name}: skipped ({exc})")
                    view = None
                if view is not None:
                    kp[c] = to_full_px(view.keypoints_px, work, cam)
                    vis[c] = view.scores >= DETECTOR_MIN_SCORE
                bar.update(1)
            keypoints.append(kp)
            visible.append(vis)
    return check_keypoints(cameras, keypoints, visible, source=source, notes=notes)


def format_report(report: CheckReport) -> str:
    """The report as text: one line per camera, then the pairs, then the verdict. No NaN: 'n/a' instead."""
    def num(value: float, width: int) -> str:
        return f"{value:>{width}.2f}" if np.isfinite(value) else f"{'n/a':>{width}}"

    lines = [f"calibration check from {report.source} keypoints, {report.frames} frames", "",
             f"{'camera':<12} {'epipolar px':>12} {'excess px':>10} {'limit px':>9} {'points':>7} {'partners':>9}"
             "  verdict"]
    for c in report.cameras:
        verdict = "FLAGGED" if c.flagged else "ok" if c.judged else "not judged"
        lines.append(f"{c.name:<12} {num(c.epipolar_px, 12)} {num(c.excess_px, 10)} {num(c.threshold_px, 9)} "
                     f"{c.points:>7d} {c.partners:>9d}  {verdict}")
    lines += ["", "pairs (median / p90 epipolar distance; excess over the best pose / limit, px):"]
    for p in report.pairs:
        judged = (f"; excess {num(p.excess_px, 0).strip()} / {num(p.limit_px, 0).strip()}"
                  f"{'' if p.consistent else '  DISAGREES'}") if p.judged else "; not judged (too few keypoints)"
        lines.append(f"  {p.a}-{p.b}: {num(p.median_px, 0).strip()} / {num(p.p90_px, 0).strip()} "
                     f"({p.points} points){judged}")
    lines += [""] + [f"note: {n}" for n in report.notes]
    lines += [c.reason for c in report.cameras if c.flagged and c.reason != report.summary]
    lines.append(report.summary)
    if report.hand_scale is not None:
        lines.append(("SCALE: " if report.scale_wrong else "scale: ") + report.hand_scale.message())
    return "\n".join(lines)
