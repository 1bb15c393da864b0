"""FreiHAND's benchmark metrics, computed as its official evaluation script computes them.

Per sample: 3D keypoint errors (21 points) and mesh vertex errors (V points), each raw and after the
similarity alignment of `alignment.py`; F-scores of the vertex sets at 5 mm and 15 mm, raw and aligned.
Summaries follow the official `EvalUtil.get_measures(0.0, 0.05, 100)`: for every point index the mean
error, the PCK curve over 100 thresholds from 0 to 50 mm (`error <= threshold`) and its area normalised to
[0, 1]; then the mean over point indices. The F-score uses per-point nearest-neighbour distances between the
two vertex sets (`distance < threshold`), averaged over samples.

Units: metres in and in the per-sample arrays; `FreiHANDScores.to_dict` reports the official names in the
official units (`*_mean3d` in centimetres, as in the script's scores.txt) plus the same errors in mm.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from workers.evaluation.alignment import align_w_scale, apply_similarity, similarity_transform

PCK_MIN_M = 0.0
PCK_MAX_M = 0.05
PCK_STEPS = 100
F_THRESHOLDS_M: tuple[float, ...] = (0.005, 0.015)


def pck_thresholds_m() -> np.ndarray:
    """(100,) the official PCK thresholds, metres: linspace(0, 0.05, 100)."""
    return np.linspace(PCK_MIN_M, PCK_MAX_M, PCK_STEPS)


@dataclass(frozen=True, eq=False)
class PckSummary:
    """Official summary of point errors over a set of samples.

    Attributes:
        mean_m: mean over point indices of each index's mean error, metres.
        median_m: mean over point indices of each index's median error, metres.
        auc: mean over point indices of the normalised area under the PCK curve, in [0, 1].
        thresholds_m: (T,) thresholds, metres.
        pck: (T,) mean over point indices of the fraction of samples with error <= threshold.
    """

    mean_m: float
    median_m: float
    auc: float
    thresholds_m: np.ndarray
    pck: np.ndarray


def summarise_errors(errors_m: np.ndarray, thresholds_m: np.ndarray | None = None) -> PckSummary:
    """Summarise (S, P) point errors (S samples, P point indices, metres) as the official EvalUtil does."""
    errors = np.asarray(errors_m, dtype=np.float64)
    if errors.ndim != 2 or errors.shape[0] == 0 or errors.shape[1] == 0:
        raise ValueError(f"errors must have shape (S, P) with S, P >= 1, got {errors.shape}")
    if not np.isfinite(errors).all() or (errors < 0).any():
        raise ValueError("errors must be finite and non-negative")
    thresholds = pck_thresholds_m() if thresholds_m is None else np.asarray(thresholds_m, dtype=np.float64)
    # (T, P): share of samples within each threshold, per point index (one threshold at a time: a (T, S, P)
    # comparison would take gigabytes for a full evaluation set's meshes).
    pck_per_point = np.stack([(errors <= t).mean(axis=0) for t in thresholds])
    norm = np.trapezoid(np.ones_like(thresholds), thresholds)
    auc_per_point = np.trapezoid(pck_per_point, thresholds, axis=0) / norm
    return PckSummary(mean_m=float(errors.mean(axis=0).mean()), median_m=float(np.median(errors, axis=0).mean()),
                      auc=float(auc_per_point.mean()), thresholds_m=thresholds, pck=pck_per_point.mean(axis=1))


@dataclass(frozen=True)
class FScore:
    """F-score of two point sets at one threshold.

    Attributes:
        f: harmonic mean of precision and recall (0 when both are 0).
        precision: share of predicted points within the threshold of some ground-truth point.
        recall: share of ground-truth points within the threshold of some predicted point.
    """

    f: float
    precision: float
    recall: float


def fscore(gt_points: np.ndarray, pred_points: np.ndarray, threshold_m: float) -> FScore:
    """F-score between (N, 3) ground-truth and (M, 3) predicted points (nearest-neighbour distances).

    The official script names these two shares the other way round; the F-score is symmetric, so its
    value is the same.
    """
    gt = np.asarray(gt_points, dtype=np.float64)
    pred = np.asarray(pred_points, dtype=np.float64)
    if gt.ndim != 2 or gt.shape[1] != 3 or pred.ndim != 2 or pred.shape[1] != 3:
        raise ValueError(f"point sets must have shape (N, 3), got {gt.shape} and {pred.shape}")
    if not threshold_m > 0:
        raise ValueError(f"threshold must be positive, got {threshold_m}")
    if len(gt) == 0 or len(pred) == 0:
        return FScore(0.0, 0.0, 0.0)
    pred_to_gt, _ = cKDTree(gt).query(pred, k=1)
    gt_to_pred, _ = cKDTree(pred).query(gt, k=1)
    precision = float((pred_to_gt < threshold_m).mean())
    recall = float((gt_to_pred < threshold_m).mean())
    f = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return FScore(f=f, precision=precision, recall=recall)


@dataclass(frozen=True, eq=False)
class SampleErrors:
    """Errors of one sample, metres.

    Attributes:
        xyz: (21,) keypoint errors.  xyz_al: (21,) after alignment.
        mesh: (V,) vertex errors, or None when the meshes have different vertex counts.
        mesh_al: (V,) after alignment, or None.
        f: F-score per threshold of F_THRESHOLDS_M, raw.  f_al: the same after alignment.
    """

    xyz: np.ndarray
    xyz_al: np.ndarray
    mesh: np.ndarray | None
    mesh_al: np.ndarray | None
    f: tuple[float, ...]
    f_al: tuple[float, ...]


def sample_errors(gt_xyz: np.ndarray, gt_verts: np.ndarray, pred_xyz: np.ndarray, pred_verts: np.ndarray,
                  f_thresholds_m: Sequence[float] = F_THRESHOLDS_M) -> SampleErrors:
    """One sample's errors as the official script computes them.

    Args:
        gt_xyz, pred_xyz: (21, 3) keypoints, metres, same frame.
        gt_verts: (V, 3) ground-truth vertices; pred_verts: (V', 3) predicted vertices, metres.
    When V' != V there is no vertex correspondence: no mesh errors, and the predicted mesh is aligned with
    the similarity estimated on the keypoints (the official script's choice).
    """
    gt_xyz, pred_xyz = np.asarray(gt_xyz, np.float64), np.asarray(pred_xyz, np.float64)
    gt_verts, pred_verts = np.asarray(gt_verts, np.float64), np.asarray(pred_verts, np.float64)
    xyz_al = align_w_scale(gt_xyz, pred_xyz)
    same_mesh = gt_verts.shape == pred_verts.shape
    if same_mesh:
        verts_al = align_w_scale(gt_verts, pred_verts)
    else:
        # The official script rotates about the vertex centroid and skips a scale factor here; we apply the
        # keypoint similarity as estimated (the same map that aligns the keypoints).
        verts_al = apply_similarity(pred_verts, similarity_transform(gt_xyz, pred_xyz))
    return SampleErrors(
        xyz=np.linalg.norm(pred_xyz - gt_xyz, axis=1),
        xyz_al=np.linalg.norm(xyz_al - gt_xyz, axis=1),
        mesh=np.linalg.norm(pred_verts - gt_verts, axis=1) if same_mesh else None,
        mesh_al=np.linalg.norm(verts_al - gt_verts, axis=1) if same_mesh else None,
        f=tuple(fscore(gt_verts, pred_verts, t).f for t in f_thresholds_m),
        f_al=tuple(fscore(gt_verts, verts_al, t).f for t in f_thresholds_m),
    )


@dataclass(frozen=True, eq=False)
class FreiHANDScores:
    """The official summary over a set of samples.

    Attributes:
        num_samples: samples evaluated.
        shape_is_mano: True when predicted and ground-truth meshes have the same vertex count (the official
            flag's name: mesh errors are only defined then).
        xyz, xyz_al: keypoint summaries, raw and aligned.
        mesh, mesh_al: vertex summaries, or None without vertex correspondence.
        f_thresholds_m: the F-score thresholds.
        f_score, f_al_score: mean F-score per threshold, raw and aligned.
    """

    num_samples: int
    shape_is_mano: bool
    xyz: PckSummary
    xyz_al: PckSummary
    mesh: PckSummary | None
    mesh_al: PckSummary | None
    f_thresholds_m: tuple[float, ...]
    f_score: tuple[float, ...]
    f_al_score: tuple[float, ...]

    def to_dict(self, with_curves: bool = True) -> dict:
        """Official output names (scores.txt): `*_mean3d` in cm, `*_auc3d` over 0-5 cm, `f_score_5`,
        `f_al_score_15`, ...; the same mean errors in mm (`*_mean3d_mm`); PCK curves as in pck_data.json
        ([thresholds in cm, pck]). Mesh values are null without vertex correspondence (the official script
        writes -1 there)."""
        out: dict = {"num_samples": self.num_samples, "shape_is_mano": self.shape_is_mano}
        curves: dict = {}
        for name, summary in (("xyz", self.xyz), ("xyz_al", self.xyz_al), ("mesh", self.mesh),
                              ("mesh_al", self.mesh_al)):
            out[f"{name}_mean3d"] = None if summary is None else summary.mean_m * 100.0
            out[f"{name}_auc3d"] = None if summary is None else summary.auc
            out[f"{name}_mean3d_mm"] = None if summary is None else summary.mean_m * 1000.0
            curves[name] = None if summary is None else [(summary.thresholds_m * 100.0).tolist(),
                                                         summary.pck.tolist()]
        for t, f, fa in zip(self.f_thresholds_m, self.f_score, self.f_al_score, strict=True):
            mm = round(t * 1000)
            out[f"f_score_{mm}"] = f
            out[f"f_al_score_{mm}"] = fa
        out["units"] = {"mean3d": "cm", "mean3d_mm": "mm", "auc3d": "PCK AUC over 0-5 cm, 100 thresholds",
                        "f_score": "F-score of vertex sets at the threshold in mm named by the key"}
        if with_curves:
            out["pck_curves"] = curves
        return out


def evaluate(gt_xyz: Sequence[np.ndarray], gt_verts: Sequence[np.ndarray], pred_xyz: Sequence[np.ndarray],
             pred_verts: Sequence[np.ndarray], *, progress: Callable[[int], None] | None = None,
             f_thresholds_m: Sequence[float] = F_THRESHOLDS_M) -> FreiHANDScores:
    """Evaluate S samples: keypoints (S, 21, 3) and vertices (S, V, 3) / (S, V', 3), metres.

    `progress(1)` is called after each sample. Like the official script, whether meshes correspond is
    decided by the vertex counts (the same for every sample here: the file readers check it).
    """
    count = len(gt_xyz)
    if count == 0:
        raise ValueError("nothing to evaluate: no samples")
    if not len(gt_verts) == len(pred_xyz) == len(pred_verts) == count:
        raise ValueError(f"sample counts differ: {count} ground-truth keypoint sets, {len(gt_verts)} ground-truth "
                         f"meshes, {len(pred_xyz)} predicted keypoint sets, {len(pred_verts)} predicted meshes")
    per_sample = []
    for i in range(count):
        per_sample.append(sample_errors(gt_xyz[i], gt_verts[i], pred_xyz[i], pred_verts[i], f_thresholds_m))
        if progress is not None:
            progress(1)
    shape_is_mano = all(s.mesh is not None for s in per_sample)

    def stack(name: str) -> np.ndarray:
        return np.stack([getattr(s, name) for s in per_sample])

    return FreiHANDScores(
        num_samples=count,
        shape_is_mano=shape_is_mano,
        xyz=summarise_errors(stack("xyz")),
        xyz_al=summarise_errors(stack("xyz_al")),
        mesh=summarise_errors(stack("mesh")) if shape_is_mano else None,
        mesh_al=summarise_errors(stack("mesh_al")) if shape_is_mano else None,
        f_thresholds_m=tuple(float(t) for t in f_thresholds_m),
        f_score=tuple(float(v) for v in stack("f").mean(axis=0)),
        f_al_score=tuple(float(v) for v in stack("f_al").mean(axis=0)),
    )
