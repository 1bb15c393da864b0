"""FreiHAND metrics on hand-built cases, and against slow, obviously-correct references."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import orthogonal_procrustes
from scipy.spatial.transform import Rotation

from workers.evaluation import (
    align_w_scale,
    evaluate,
    fscore,
    pck_thresholds_m,
    sample_errors,
    similarity_transform,
    summarise_errors,
)


def sparse_hand(rng: np.random.Generator, n: int, spacing_m: float = 0.06) -> np.ndarray:
    """(n, 3) points at least `spacing_m` apart, so that each point's nearest neighbour in a slightly moved
    copy is its own image (F-scores then follow from the per-point errors)."""
    grid = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3) * spacing_m
    return grid[rng.permutation(len(grid))[:n]] + rng.normal(0, 0.001, (n, 3))


@pytest.fixture
def case() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    return sparse_hand(rng, 21), sparse_hand(rng, 40)


def reference_auc(errors: np.ndarray) -> float:
    """Slow reference of the official EvalUtil: per point index, PCK over the thresholds, trapezoids by hand."""
    thresholds = np.linspace(0.0, 0.05, 100)
    aucs = []
    for p in range(errors.shape[1]):
        curve = [np.mean([e <= t for e in errors[:, p]]) for t in thresholds]
        area = sum((thresholds[i + 1] - thresholds[i]) * (curve[i] + curve[i + 1]) / 2 for i in range(99))
        aucs.append(area / 0.05)
    return float(np.mean(aucs))


def test_perfect_prediction_scores_auc_one_and_zero_error(case):
    xyz, verts = case
    scores = evaluate([xyz], [verts], [xyz.copy()], [verts.copy()]).to_dict()
    for name in ("xyz", "mesh"):
        assert scores[f"{name}_auc3d"] == 1.0
        assert scores[f"{name}_mean3d"] == 0.0
    for name in ("xyz_al", "mesh_al"):
        # The alignment leaves rounding-sized errors (the official 1e-8 added to both norms scales by
        # 1 - 1e-7); only exact zeros pass the first threshold (0 mm), so the area lacks half a step there.
        assert scores[f"{name}_mean3d_mm"] < 1e-4
        assert scores[f"{name}_auc3d"] == pytest.approx(1 - 0.5 / 99)
    for key in ("f_score_5", "f_al_score_5", "f_score_15", "f_al_score_15"):
        assert scores[key] == pytest.approx(1.0)
    assert scores["shape_is_mano"] is True and scores["num_samples"] == 1


def test_known_shift_gives_its_error_and_alignment_removes_it(case):
    xyz, verts = case
    shift = np.array([0.0036, 0.0, 0.0048])  # 6 mm
    scores = evaluate([xyz], [verts], [xyz + shift], [verts + shift]).to_dict()
    assert scores["xyz_mean3d_mm"] == pytest.approx(6.0)
    assert scores["xyz_mean3d"] == pytest.approx(0.6)  # official unit: cm
    assert scores["mesh_mean3d_mm"] == pytest.approx(6.0)
    # PCK is 0 below 6 mm and 1 from there: area of that step over 0..50 mm, as the official trapezoids see it.
    t = pck_thresholds_m()
    expected = np.trapezoid((t >= 0.006).astype(float), t) / 0.05
    assert scores["xyz_auc3d"] == pytest.approx(expected)
    assert scores["xyz_auc3d"] == pytest.approx(reference_auc(np.full((1, 21), 0.006)))
    assert scores["xyz_al_mean3d_mm"] == pytest.approx(0.0, abs=1e-4)
    assert scores["mesh_al_mean3d_mm"] == pytest.approx(0.0, abs=1e-4)
    # Every vertex is 6 mm from its twin: not within 5 mm, within 15 mm.
    assert scores["f_score_5"] == pytest.approx(0.0)
    assert scores["f_score_15"] == pytest.approx(1.0)
    assert scores["f_al_score_5"] == pytest.approx(1.0)


def test_known_rotation_is_removed_by_alignment(case):
    xyz, verts = case
    R = Rotation.from_rotvec([0.0, 0.0, np.deg2rad(30)]).as_matrix()
    centre = xyz.mean(0)
    rotated_xyz = (xyz - centre) @ R.T + centre
    rotated_verts = (verts - centre) @ R.T + centre
    errors = sample_errors(xyz, verts, rotated_xyz, rotated_verts)
    # A rotation by 30 degrees about z moves a point by 2 r sin(15 deg), r its distance from the z axis.
    r = np.linalg.norm((xyz - centre)[:, :2], axis=1)
    np.testing.assert_allclose(errors.xyz, 2 * r * np.sin(np.deg2rad(15)), atol=1e-12)
    np.testing.assert_allclose(errors.xyz_al, 0.0, atol=1e-7)
    np.testing.assert_allclose(errors.mesh_al, 0.0, atol=1e-7)
    transform = similarity_transform(xyz, rotated_xyz)
    np.testing.assert_allclose(transform.R, R.T, atol=1e-9)  # maps the prediction back
    assert transform.scale == pytest.approx(1.0)


def test_scale_and_translation_are_removed_by_alignment(case):
    xyz, _ = case
    centre = xyz.mean(0)
    pred = 1.7 * (xyz - centre) + centre + np.array([0.1, -0.2, 0.05])
    np.testing.assert_allclose(align_w_scale(xyz, pred), xyz, atol=1e-7)
    assert similarity_transform(xyz, pred).scale == pytest.approx(1 / 1.7)


def test_alignment_matches_scipy_orthogonal_procrustes_reference():
    """The official script's recipe with scipy's solver, on random (noisy) sets."""
    rng = np.random.default_rng(0)
    for _ in range(5):
        gt = rng.normal(0, 0.05, (21, 3))
        pred = gt @ Rotation.random(random_state=rng.integers(1000)).as_matrix().T * 1.3 + rng.normal(0, 0.01, (21, 3))
        g, p = gt - gt.mean(0), pred - pred.mean(0)
        gn, pn = np.linalg.norm(g) + 1e-8, np.linalg.norm(p) + 1e-8
        R, s = orthogonal_procrustes(g / gn, p / pn)
        expected = (p / pn) @ R.T * s * gn + gt.mean(0)
        np.testing.assert_allclose(align_w_scale(gt, pred), expected, atol=1e-12)


def test_summary_matches_slow_reference_on_random_errors():
    rng = np.random.default_rng(1)
    errors = np.abs(rng.normal(0.02, 0.015, (30, 21)))
    summary = summarise_errors(errors)
    assert summary.auc == pytest.approx(reference_auc(errors))
    assert summary.mean_m == pytest.approx(errors.mean())
    assert summary.median_m == pytest.approx(np.mean([np.median(errors[:, p]) for p in range(21)]))
    assert summary.pck[0] == pytest.approx(np.mean(errors <= 0.0))
    assert summary.pck[-1] == pytest.approx(np.mean(errors <= 0.05))


def test_fscore_on_a_hand_built_pair():
    gt = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    pred = np.array([[0.0, 0.004, 0], [0.5, 0, 0], [1.0, 0.0, 0.02]])
    score = fscore(gt, pred, 0.005)
    assert score.precision == pytest.approx(1 / 3)  # one of three predicted points near the ground truth
    assert score.recall == pytest.approx(1 / 2)  # one of two ground-truth points covered
    assert score.f == pytest.approx(2 * (1 / 3) * (1 / 2) / (1 / 3 + 1 / 2))
    assert fscore(gt, pred, 0.05).f == pytest.approx(2 * (2 / 3) * 1.0 / (2 / 3 + 1.0))


def test_meshes_without_correspondence_have_no_mesh_errors_but_fscores(case):
    xyz, verts = case
    scores = evaluate([xyz], [verts], [xyz], [verts[:30]]).to_dict()
    assert scores["shape_is_mano"] is False
    assert scores["mesh_mean3d"] is None and scores["mesh_al_auc3d"] is None
    assert scores["f_score_5"] == pytest.approx(2 * 1.0 * 0.75 / 1.75)  # all 30 predicted near, 30/40 covered


def test_bad_arguments_are_refused(case):
    xyz, verts = case
    with pytest.raises(ValueError, match="no samples"):
        evaluate([], [], [], [])
    with pytest.raises(ValueError, match="sample counts differ"):
        evaluate([xyz], [verts], [xyz, xyz], [verts])
    with pytest.raises(ValueError, match="same shape"):
        similarity_transform(xyz, xyz[:20])
    with pytest.raises(ValueError, match="non-finite"):
        align_w_scale(xyz, np.full_like(xyz, np.nan))
    with pytest.raises(ValueError, match="threshold"):
        fscore(verts, verts, 0.0)
