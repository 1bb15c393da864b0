"""The fitting engine recovers known hands from exact synthetic inputs and refuses bad input."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from workers.fitting.config import FitConfig
from workers.fitting.engine import FittingEngine
from workers.fitting.inputs import FitInputError, FrameObservations


@pytest.fixture(scope="module")
def engine(hand, rig):
    return FittingEngine(hand, rig, FitConfig())


def test_recovers_known_hands_from_exact_inputs(engine, known_frames):
    frames, truth = known_frames
    progress = []
    results = engine.fit(frames, progress=lambda fraction, message: progress.append(fraction))
    for b, result in enumerate(results):
        vertex_mm = 1000 * np.linalg.norm(result.vertices - truth["vertices"][b], axis=1).mean()
        keypoint_mm = 1000 * np.linalg.norm(result.keypoints - truth["keypoints"][b], axis=1).mean()
        assert vertex_mm < 6.0, vertex_mm
        assert keypoint_mm < 6.0, keypoint_mm
        d = result.diagnostics
        assert np.nanmean(d.residual_2d_px) < 1.5
        assert np.all(d.iou_per_view > 0.6) and np.mean(d.iou_per_view) > 0.8
        assert set(d.loss_terms) >= {"kp2d", "seg", "shape", "pose", "nn", "limits"}
        assert result.theta.shape == (61,)
        assert len(result.model_masks) == 8 and result.model_masks[0].shape == (256, 320)
    assert progress[-1] == 1.0 and progress == sorted(progress)


def test_deterministic_for_a_seed(hand, rig, known_frames):
    frames, _ = known_frames
    config = FitConfig(global_iterations=10, full_iterations=15, seed=3)
    a = FittingEngine(hand, rig, config).fit(frames[:1])[0]
    b = FittingEngine(hand, rig, config).fit(frames[:1])[0]
    assert np.array_equal(a.vertices, b.vertices)


def test_silhouette_improves_over_keypoints_alone(hand, rig, known_frames):
    frames, truth = known_frames
    errors = {}
    for silhouette in (True, False):
        result = FittingEngine(hand, rig, FitConfig(use_silhouette=silhouette)).fit(frames[1:])[0]
        errors[silhouette] = np.linalg.norm(result.vertices - truth["vertices"][1], axis=1).mean()
    assert errors[True] < errors[False]


def test_a_mislabeled_click_does_not_drag_the_robust_fit(hand, rig, known_frames):
    frames, truth = known_frames
    clicks = frames[0].clicks_px.copy()
    clicks[2, 8] = clicks[2, 20]  # index tip clicked on the pinky tip in one view
    bad = dataclasses.replace(frames[0], clicks_px=clicks, masks=None)
    errors = {}
    for robust in ("geman_mcclure", "none"):
        result = FittingEngine(hand, rig, FitConfig(robust=robust)).fit([bad])[0]
        errors[robust] = np.linalg.norm(result.keypoints[8] - truth["keypoints"][0][8])
    assert errors["geman_mcclure"] < errors["none"]


def _frame(rig, **changes):
    clicks = np.full((len(rig), 21, 2), 100.0)
    weights = np.zeros((len(rig), 21))
    weights[:, [0, 4, 8, 12, 16, 20]] = 1.0
    return dataclasses.replace(FrameObservations(clicks, weights), **changes)


@pytest.mark.parametrize(("make", "message"), [
    (lambda rig: FrameObservations.empty(len(rig)), "no clicks and no 3D keypoints"),
    (lambda rig: _frame(rig, click_weights=np.eye(len(rig), 21) * 0 + np.pad(np.ones((1, 21)), ((0, 7), (0, 0)))),
     "clicks in at least two views"),
    (lambda rig: _frame(rig, clicks_px=np.full((len(rig), 21, 2), np.inf)), "is not a finite number"),
    (lambda rig: _frame(rig, clicks_px=np.full((len(rig), 21, 2), 5000.0)), "outside its 320x256 image"),
    (lambda rig: _frame(rig, clicks_px=np.zeros((3, 21, 2))), r"clicks_px must have shape \(8, 21, 2\)"),
    (lambda rig: _frame(rig, click_weights=-np.ones((len(rig), 21))), "finite and non-negative"),
    (lambda rig: _frame(rig, masks=tuple(np.zeros((10, 10), bool) for _ in rig)),
     "mask of view cam0 has size 10x10, the camera's image is 320x256"),
    (lambda rig: _frame(rig, masks=(np.zeros((256, 320), bool),)), "expected 8 masks"),
    (lambda rig: _frame(rig, keypoints_3d=np.full((21, 3), np.inf)), "infinite or implausible"),
])
def test_bad_input_fails_with_a_clear_error(engine, rig, make, message):
    with pytest.raises(FitInputError, match=message):
        engine.fit([make(rig)])


def test_two_located_keypoints_cannot_place_the_hand(engine, rig, known_frames):
    frames, _ = known_frames
    weights = np.zeros_like(frames[0].click_weights)
    weights[:, [0, 4]] = 1.0  # wrist and thumb tip only: the hand's roll is undetermined
    obs = dataclasses.replace(frames[0], click_weights=weights, masks=None)
    with pytest.raises(FitInputError, match="frame 0: at least three keypoints must be located in 3D"):
        engine.fit([obs])


def test_fit_from_3d_keypoints_alone(hand, rig, known_frames):
    _, truth = known_frames
    obs = FrameObservations.empty(len(rig))
    obs = dataclasses.replace(obs, keypoints_3d=truth["keypoints"][0])
    config = FitConfig().with_weights(kp3d=1000.0)
    result = FittingEngine(hand, rig, config).fit([obs])[0]
    assert 1000 * np.linalg.norm(result.keypoints - truth["keypoints"][0], axis=1).mean() < 5.0
    assert np.all(np.isnan(result.diagnostics.iou_per_view))


def test_the_papers_adam_schedule_also_recovers_the_hand(hand, rig, known_frames):
    frames, truth = known_frames
    result = FittingEngine(hand, rig, FitConfig.adam()).fit(frames[:1])[0]
    assert result.diagnostics.iterations == 200
    assert 1000 * np.linalg.norm(result.vertices - truth["vertices"][0], axis=1).mean() < 8.0


def test_frames_of_a_batch_stay_independent(engine, known_frames):
    frames, _ = known_frames
    together = engine.fit(frames)
    for b, frame in enumerate(frames):
        alone = engine.fit([frame])[0]
        assert np.abs(alone.vertices - together[b].vertices).max() < 1e-4  # metres
        assert alone.diagnostics.iterations == together[b].diagnostics.iterations


def test_levenberg_marquardt_lowers_the_objective_more_than_its_first_stage(hand, rig, known_frames):
    frames, _ = known_frames
    placed = FittingEngine(hand, rig, FitConfig(full_iterations=0)).fit(frames[1:])[0]
    fitted = FittingEngine(hand, rig, FitConfig()).fit(frames[1:])[0]
    assert sum(fitted.diagnostics.loss_terms.values()) < 0.5 * sum(placed.diagnostics.loss_terms.values())
    assert fitted.diagnostics.iterations <= FitConfig().global_iterations + FitConfig().full_iterations


@pytest.mark.parametrize(("changes", "message"), [
    ({"finalists": 0}, "finalists must be an integer >= 1"),
    ({"lm_damping": float("nan")}, "lm_damping must be a positive finite number"),
    ({"optimizer": "sgd"}, "optimizer must be"),
    ({"coverage_tangent_weight": -1.0}, "coverage_tangent_weight must be >= 0"),
    ({"num_pca_comps": 46}, "num_pca_comps must be at most 45"),
])
def test_bad_config_fails_with_a_clear_error(changes, message):
    with pytest.raises(ValueError, match=message):
        FitConfig(**changes)
    with pytest.raises(ValueError, match=r"LossWeights\.seg"):
        FitConfig().with_weights(seg=-1.0)


@pytest.mark.parametrize("config", [FitConfig(), FitConfig.adam(global_iterations=5, full_iterations=20)],
                         ids=["levenberg_marquardt", "adam"])
def test_refine_continues_an_earlier_fit_from_its_parameters(hand, rig, known_frames, config):
    frames, truth = known_frames
    engine = FittingEngine(hand, rig, config)
    placed = FittingEngine(hand, rig, dataclasses.replace(config, full_iterations=0)).fit(frames[1:])[0]
    refined = engine.refine(frames[1:], [placed])[0]
    # From the placement, the second stage alone lowers the objective and reaches the hand.
    assert sum(refined.diagnostics.loss_terms.values()) < sum(placed.diagnostics.loss_terms.values())
    assert refined.diagnostics.iterations <= config.full_iterations
    assert np.abs(refined.vertices - truth["vertices"][1]).mean() < \
        np.abs(placed.vertices - truth["vertices"][1]).mean()
    if config.optimizer == "levenberg_marquardt":
        # From a converged fit there is nothing left to gain: it stays where it was.
        fitted = engine.fit(frames[1:])[0]
        again = engine.refine(frames[1:], [fitted])[0]
        assert np.abs(again.vertices - fitted.vertices).max() < 1e-3  # metres
    with pytest.raises(FitInputError, match="one earlier fit per frame"):
        engine.refine(frames, [placed])
    with pytest.raises(FitInputError, match="hand model"):
        engine.refine(frames[1:], [dataclasses.replace(placed, hand_model="another")])


def test_masks_prepared_once_fit_as_masks_each_fit_prepares(hand, rig, known_frames):
    """`fit` and `refine` given `prepare_masks` of their frames (as `fit_reweighted` shares it between its two fits)
    fit exactly as they do preparing the masks themselves; masks of other frames are refused."""
    frames = [dataclasses.replace(f, masks_include_forearm=True) for f in known_frames[0]]  # cut at the wrist
    engine = FittingEngine(hand, rig, FitConfig(full_iterations=8))
    prepared = engine.prepare_masks(frames)
    assert prepared.matches(frames) and not prepared.matches(frames[::-1])
    assert prepared.outside_px.shape == (2, len(rig), max(c.height for c in rig), max(c.width for c in rig))
    has_mask = [[m is not None and m.any() for m in f.masks] for f in frames]
    assert prepared.has_mask.tolist() == has_mask
    assert [[p is not None for p in row] for row in prepared.pixels] == has_mask  # undistorted for the cut
    first = engine.fit(frames, prepared=prepared)
    for a, b in zip(first, engine.fit(frames), strict=True):
        assert np.array_equal(a.vertices, b.vertices)
        assert np.array_equal(a.diagnostics.iou_per_view, b.diagnostics.iou_per_view, equal_nan=True)
    for a, b in zip(engine.refine(frames, first, prepared=prepared), engine.refine(frames, first), strict=True):
        assert np.array_equal(a.vertices, b.vertices)
    with pytest.raises(ValueError, match="prepare_masks"):
        engine.fit(frames[:1], prepared=prepared)
    with pytest.raises(ValueError, match="prepare_masks"):
        engine.refine(frames[::-1], first[::-1], prepared=prepared)
