"""The detector-backed MVNet (heatmap_source="detector"): maps rendered where the keypoints are, in the crop frame
after every crop transform; configuration in the checkpoint; learning from (perfect) detections; the paper-only
fallback when the model files are missing. The detector itself is not run here (tests/workers/detector does)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from tests.support.training import BY_STEPS_S
from workers.capture.reader import load_frame_images, load_ground_truth
from workers.detector import DetectorUnavailableError
from workers.detector.keypoint_offsets import KeypointOffsets, PoseCorrection
from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig
from workers.nets.checkpoints import CheckpointError, load_model
from workers.nets.configs import CONFIGS, DETECTOR_WINDOW_M, MVNetConfig, config_digest, get_config, paper_only
from workers.nets.data import augment_mvnet_batch, build_mvnet_dataset, crop_views
from workers.nets.detections import FrameDetections, detector_backed
from workers.nets.keypoint_maps import image_to_crop_px, render_keypoint_maps
from workers.nets.losses import refined_argmax
from workers.nets.mvnet import MVNet
from workers.nets.predict import predict_from_crops, predict_keypoints, window_scores
from workers.nets.train import train_mvnet
from workers.nets.unproject import project_batched

# tiny's sizes, detector-backed, no augmentation that the two test frames cannot afford.
TINY_DETECTOR = replace(get_config("tiny").mvnet, heatmap_residual=True, heatmap_source="detector",
                        detector_sigma_px=1.0)


def perfect_detections(frames, cameras, score: float = 1.0, shift_m: np.ndarray | None = None
                       ) -> list[FrameDetections]:
    """What a perfect detector would report: the ground truth's projections, every keypoint scored `score`;
    with `shift_m` (3,) a biased one, whose keypoints all sit that far off the truth (metres, world frame)."""
    out = []
    for frame in frames:
        gt = load_ground_truth(frame)
        points = gt.keypoints_3d + (0 if shift_m is None else shift_m)
        pixels, _ = project_points(points, list(cameras))
        out.append(FrameDetections(pixels.astype(np.float32), np.full(pixels.shape[:2], score, np.float32),
                                   points.copy(), np.ones(21)))
    return out


def test_rendered_maps_peak_at_the_keypoints_pixels():
    rng = np.random.default_rng(0)
    S = 24
    pixels = rng.integers(0, S, (2, 3, 21, 2)).astype(np.float32)  # pixel centres of a map as large as the crop
    weights = rng.uniform(0.2, 1.0, (2, 3, 21)).astype(np.float32)
    maps = render_keypoint_maps(torch.as_tensor(pixels), torch.as_tensor(weights), S, S, 1.5)
    assert maps.shape == (2, 3, 21, S, S)
    flat = maps.flatten(-2).numpy()
    np.testing.assert_array_equal(np.stack([flat.argmax(-1) % S, flat.argmax(-1) // S], -1), pixels)
    np.testing.assert_allclose(flat.max(-1), weights, rtol=1e-6)
    # No detection (NaN) or a zero score: an empty map, not a peak at the origin.
    pixels[0, 1, 4] = np.nan
    weights[1, 2, 7] = 0
    maps = render_keypoint_maps(torch.as_tensor(pixels), torch.as_tensor(weights), S, S, 1.5)
    assert float(maps[0, 1, 4].abs().max()) == 0 and float(maps[1, 2, 7].abs().max()) == 0
    with pytest.raises(ValueError, match="disagree"):
        render_keypoint_maps(torch.zeros(1, 2, 21, 2), torch.zeros(1, 2, 20), S, S, 1.0)


def test_image_keypoints_land_on_the_crops_projection_after_augmentation(tiny_capture, tiny_frames):
    """Keypoints detected in the full (distorted) image, moved by K_crop K^-1 of an augmented crop, are where the 3D
    keypoints project with the crop's own intrinsics; the rendered map peaks at that pixel."""
    config = replace(TINY_DETECTOR, crop_rotation_deg=40.0, crop_scale=0.2, center_jitter_m=0.01)
    cameras = tiny_capture.cameras
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, config,
                                  detections=perfect_detections(tiny_frames, cameras))
    batch = augment_mvnet_batch(dataset, np.arange(len(dataset)), config, np.random.default_rng(3))
    K_crop = torch.as_tensor(batch["K_crop"], dtype=torch.float64)
    from workers.geometry.projection import stack_cameras

    cams = stack_cameras(list(cameras), dtype=torch.float64)
    expected, _ = project_batched(torch.as_tensor(batch["keypoints_3d"], dtype=torch.float64), K_crop, cams["dist"],
                                  cams["R"], cams["t"])
    np.testing.assert_allclose(batch["detector_px"], expected.numpy(), atol=2e-3)
    S = config.crop_px
    maps = render_keypoint_maps(torch.as_tensor(batch["detector_px"]), torch.as_tensor(batch["detector_scores"]),
                                S, S, 1.0)
    nearest = np.rint(expected.numpy()).astype(int)
    inside = ((nearest >= 0) & (nearest < S)).all(-1)
    assert inside.mean() > 0.5
    flat = maps.flatten(-2).numpy()
    peak = np.stack([flat.argmax(-1) % S, flat.argmax(-1) // S], -1)
    np.testing.assert_array_equal(peak[inside], nearest[inside])


def test_image_to_crop_px_is_the_crop_transform():
    cameras = default_rig(96)
    center = np.array([0.02, 0.0, -0.01])
    points = center + np.random.default_rng(1).normal(0, 0.04, (21, 3))
    _, K_crop, valid, _ = crop_views([np.zeros((c.height, c.width, 3), np.uint8) for c in cameras], cameras, center,
                                     32, 0.15)
    assert valid.all()
    image_px, _ = project_points(points, cameras)  # (C, 21, 2) with distortion
    got = image_to_crop_px(image_px, K_crop, np.stack([c.K for c in cameras]))
    for c, cam in enumerate(cameras):
        A = K_crop[c] @ np.linalg.inv(cam.K)
        want = (A[:2, :2] @ image_px[c].T).T + A[:2, 2]
        np.testing.assert_allclose(got[c], want, atol=1e-9)


def test_configuration_and_digest():
    paper_cfg = get_config("cpu-small").mvnet
    detector_cfg = get_config("cpu-small-detector-coarse").mvnet  # the first design: image features beside the maps
    assert paper_cfg.heatmap_source == "learned" and detector_cfg.heatmap_source == "detector"
    assert get_config("cpu-small-detector").mvnet.heatmap_source == "detector"
    # The new fields leave paper-only digests alone (existing checkpoints still load) ...
    assert config_digest(paper_cfg) == config_digest(replace(paper_cfg, detector_sigma_px=3.0))
    # ... and make a detector-backed network another architecture, its map width part of it.
    assert config_digest(detector_cfg) != config_digest(replace(detector_cfg, heatmap_source="learned"))
    assert config_digest(detector_cfg) != config_digest(replace(detector_cfg, detector_sigma_px=2.0))
    assert paper_only(get_config("cpu-small-detector")) is CONFIGS["cpu-small"]
    assert paper_only(get_config("cpu-small-detector-coarse")) is CONFIGS["cpu-small"]
    # Unnamed detector-backed configurations fall back to the same sizes with the learned 2D head and the 2D CNN.
    unnamed = paper_only(replace(get_config("tiny"), name="tiny-detector", mvnet=TINY_AGREEMENT))
    assert unnamed.mvnet.heatmap_source == "learned" and unnamed.mvnet.unet_image_features
    assert MVNet(unnamed.mvnet).encoder is not None
    assert paper_only(get_config("cpu-small")) is CONFIGS["cpu-small"]
    with pytest.raises(ValueError, match="heatmap_residual=True"):
        MVNetConfig(heatmap_source="detector")
    with pytest.raises(ValueError, match="'learned' or 'detector'"):
        MVNetConfig(heatmap_source="mediapipe")  # type: ignore[arg-type]
    MVNetConfig(heatmap_residual=True, heatmap_source="detector")  # no learned 2D head needed


def test_detector_backed_mvnet_needs_detections(tiny_capture, tiny_frames, tmp_path):
    model = MVNet(TINY_DETECTOR)
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, TINY_DETECTOR,
                                  detections=perfect_detections(tiny_frames, tiny_capture.cameras))
    with pytest.raises(ValueError, match="detector_px"):
        predict_from_crops(model, dataset.crops, dataset.K_crop, dataset.centers_world, dataset.cameras)
    with pytest.raises(ValueError, match="detections"):
        predict_keypoints(model, [{}], dataset.cameras, dataset.centers_world[:1])
    paper_data = build_mvnet_dataset(tiny_capture, tiny_frames, get_config("tiny").mvnet)
    with pytest.raises(ValueError, match="no detections"):
        train_mvnet(paper_data, TINY_DETECTOR, budget_s=10, checkpoint_dir=tmp_path, max_steps=1)
    with pytest.raises(ValueError, match="2 entries for"):
        build_mvnet_dataset(tiny_capture, tiny_frames[:1], TINY_DETECTOR, detections=dataset_detections(dataset))


def dataset_detections(dataset) -> list[FrameDetections]:
    return [FrameDetections(p, s, np.full((21, 3), np.nan), np.full(21, np.nan))
            for p, s in zip(dataset.detector_px, dataset.detector_scores, strict=True)]


# A detector whose keypoints all sit 3 cm off (more than a voxel of tiny's grid): the 3D network must learn it.
BIAS_M = np.array([0.03, 0.0, 0.0])


@pytest.fixture(scope="module")
def trained_on_biased_detections(tiny_capture, tiny_frames, tmp_path_factory):
    detections = perfect_detections(tiny_frames, tiny_capture.cameras, shift_m=BIAS_M)
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, TINY_DETECTOR, detections=detections)
    result = train_mvnet(dataset, TINY_DETECTOR, budget_s=BY_STEPS_S,
                         checkpoint_dir=tmp_path_factory.mktemp("det"), max_steps=150, seed=2)
    return dataset, result


def _error_mm(model, dataset) -> float:
    pred = predict_from_crops(model, dataset.crops, dataset.K_crop, dataset.centers_world, dataset.cameras,
                              dataset.view_valid, detector_px=_crop_px(dataset),
                              detector_scores=dataset.detector_scores)
    return float(1000 * np.linalg.norm(pred.keypoints_3d - dataset.keypoints_3d, axis=-1).mean())


def _crop_px(dataset) -> np.ndarray:
    return image_to_crop_px(dataset.detector_px, dataset.K_crop, np.stack([c.K for c in dataset.cameras]))


def test_untrained_network_triangulates_perfect_detections(tiny_capture, tiny_frames):
    """The U-Net's correction starts at zero: fed perfect keypoints, the untrained network is their triangulation."""
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, TINY_DETECTOR,
                                  detections=perfect_detections(tiny_frames, tiny_capture.cameras))
    torch.manual_seed(0)
    assert _error_mm(MVNet(TINY_DETECTOR).eval(), dataset) < 0.2 * 1000 * TINY_DETECTOR.voxel_m  # 5 mm


def test_training_learns_the_detectors_bias(trained_on_biased_detections):
    dataset, result = trained_on_biased_detections
    torch.manual_seed(2)
    untrained = MVNet(TINY_DETECTOR).eval()
    trained_mm, untrained_mm = _error_mm(result.model, dataset), _error_mm(untrained, dataset)
    assert untrained_mm > 0.8 * 1000 * np.linalg.norm(BIAS_M), untrained_mm  # untrained: where the detector says
    assert trained_mm < 0.8 * untrained_mm, (trained_mm, untrained_mm)  # 150 steps: 30 -> 20.5 mm here
    # Its confidence (eq. 8) falls when the detections lose their scores (the residual's heat goes with them).
    pred = predict_from_crops(result.model, dataset.crops, dataset.K_crop, dataset.centers_world, dataset.cameras,
                              detector_px=_crop_px(dataset), detector_scores=dataset.detector_scores)
    weak = predict_from_crops(result.model, dataset.crops, dataset.K_crop, dataset.centers_world, dataset.cameras,
                              detector_px=_crop_px(dataset), detector_scores=0.2 * dataset.detector_scores)
    assert np.all(weak.sample_confidence < pred.sample_confidence)


def test_checkpoint_records_the_detector_configuration(trained_on_biased_detections):
    dataset, result = trained_on_biased_detections
    assert result.metadata["config"]["heatmap_source"] == "detector"
    assert result.metadata["config"]["detector_sigma_px"] == TINY_DETECTOR.detector_sigma_px
    model, meta = load_model(result.checkpoint, "mvnet")
    assert model.config == TINY_DETECTOR and meta["config_digest"] == config_digest(TINY_DETECTOR)
    np.testing.assert_allclose(_error_mm(model, dataset), _error_mm(result.model, dataset), atol=1e-4)
    with pytest.raises(CheckpointError, match="does not fit"):
        load_model(result.checkpoint, "mvnet", replace(TINY_DETECTOR, heatmap_source="learned", aux_2d_weight=1.0))


def test_missing_model_files_fall_back_to_the_paper_only_path(tiny_capture, tiny_frames, tmp_path, monkeypatch):
    monkeypatch.setenv("HANDLOOP_DETECTOR_DIR", str(tmp_path / "no-models"))
    config, message = detector_backed(get_config("cpu-small-detector"))
    assert config is CONFIGS["cpu-small"]
    assert "not available" in message and "is missing" in message and "paper-only" in message
    assert detector_backed(get_config("tiny")) == (get_config("tiny"), None)
    with pytest.raises(DetectorUnavailableError, match="is missing"):
        build_mvnet_dataset(tiny_capture, tiny_frames, TINY_DETECTOR)
    # The paper-only counterpart of a detector-backed configuration trains and predicts without the detector.
    fallback, _ = detector_backed(replace(get_config("tiny"), name="tiny-detector", mvnet=TINY_DETECTOR))
    assert fallback.mvnet.heatmap_source == "learned"
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, fallback.mvnet)
    result = train_mvnet(dataset, fallback, budget_s=30, checkpoint_dir=tmp_path / "ckpt", max_steps=2)
    pred = predict_from_crops(result.model, dataset.crops, dataset.K_crop, dataset.centers_world, dataset.cameras)
    assert np.isfinite(pred.keypoints_3d).all()


# Detector-backed, the U-Net on the detector's maps alone, the residual a weighted average of the views' Gaussians.
TINY_AGREEMENT = replace(TINY_DETECTOR, detector_residual="agreement", unet_image_features=False, aux_2d_weight=0.0)


def test_agreement_and_maps_only_fields_validate_and_enter_the_digest():
    base = get_config("cpu-small").mvnet
    detector_cfg = get_config("cpu-small-detector").mvnet
    # Earlier digests stay as they were where the new fields keep their defaults.
    assert config_digest(base) == config_digest(replace(base, detector_residual="views", unet_image_features=True))
    views = replace(TINY_AGREEMENT, detector_residual="views")
    assert config_digest(TINY_AGREEMENT) != config_digest(views)
    assert config_digest(TINY_AGREEMENT) != config_digest(replace(TINY_AGREEMENT, unet_image_features=True))
    assert config_digest(detector_cfg) != config_digest(replace(detector_cfg, grid_size=2 * detector_cfg.grid_size))
    with pytest.raises(ValueError, match="'views', 'agreement' or 'likelihood'"):
        replace(TINY_DETECTOR, detector_residual="mean")
    with pytest.raises(ValueError, match="unet_image_features=False needs"):
        replace(get_config("tiny").mvnet, unet_image_features=False)  # learned maps need the 2D CNN
    with pytest.raises(ValueError, match="unet_image_features=False needs"):
        replace(TINY_DETECTOR, unet_image_features=False, aux_2d_weight=1.0)  # a 2D head without a 2D CNN
    model = MVNet(TINY_AGREEMENT)
    assert model.encoder is None and model.head_2d is None


def test_agreement_residual_peaks_at_one_where_the_views_agree(tiny_capture, tiny_frames):
    """Untrained (zero head), perfect keypoints: the agreement residual's peak is ~1 whatever the detector's score
    level (eq. 8 then reads the views' agreement, on the scale of the peak-normalised targets); the "views" residual
    scales with the scores; both read out the triangulation."""
    cameras = tiny_capture.cameras
    confidences = {}
    for name, config in (("agreement", TINY_AGREEMENT), ("views", replace(TINY_DETECTOR, aux_2d_weight=0.0)),
                         ("likelihood", replace(TINY_AGREEMENT, detector_residual="likelihood"))):
        for score in (1.0, 0.4):
            dataset = build_mvnet_dataset(tiny_capture, tiny_frames, config,
                                          detections=perfect_detections(tiny_frames, cameras, score=score))
            torch.manual_seed(0)
            model = MVNet(config).eval()
            pred = predict_from_crops(model, dataset.crops, dataset.K_crop, dataset.centers_world, dataset.cameras,
                                      dataset.view_valid, detector_px=_crop_px(dataset),
                                      detector_scores=dataset.detector_scores)
            err = 1000 * np.linalg.norm(pred.keypoints_3d - dataset.keypoints_3d, axis=-1)
            assert err.mean() < 0.2 * 1000 * config.voxel_m, (name, score, err.mean())
            confidences[name, score] = pred.sample_confidence
    np.testing.assert_allclose(confidences["agreement", 0.4], confidences["agreement", 1.0], rtol=1e-4)
    assert np.all(confidences["agreement", 1.0] > 0.6)  # < 1: the peak falls between voxel centres of 25 mm
    np.testing.assert_allclose(confidences["views", 0.4], 0.4 * confidences["views", 1.0], rtol=1e-4)
    # The likelihood has no rays: its peak falls off less between voxel centres than the averages' does.
    np.testing.assert_allclose(confidences["likelihood", 0.4], confidences["likelihood", 1.0], rtol=1e-4)
    assert np.all(confidences["likelihood", 1.0] > confidences["agreement", 1.0])


def test_likelihood_volume_is_one_at_the_keypoint_and_falls_off_with_reprojection_distance():
    from workers.geometry.projection import stack_cameras
    from workers.nets.keypoint_maps import likelihood_volume

    cameras = default_rig(96)
    center = np.array([0.01, -0.02, 0.0])
    point = center + np.array([0.0125, -0.0125, 0.0125])  # a voxel centre of an 8-voxel grid of side 0.2 m
    _, K_crop, valid, _ = crop_views([np.zeros((c.height, c.width, 3), np.uint8) for c in cameras], cameras, center,
                                     32, 0.15)
    assert valid.all()
    cams = stack_cameras(list(cameras))
    K_t = torch.as_tensor(K_crop[None], dtype=torch.float32)
    px, _ = project_batched(torch.as_tensor(point[None, None], dtype=torch.float32), K_t, cams["dist"], cams["R"],
                            cams["t"])  # (1, C, 1, 2)
    keypoints = px.expand(1, len(cameras), 2, 2).clone()
    keypoints[:, 0, 1] = float("nan")  # keypoint 1: view 0 found nothing
    weights = torch.full((1, len(cameras), 2), 0.7)
    volume = likelihood_volume(keypoints, weights, K_t, cams["dist"], cams["R"], cams["t"],
                               torch.as_tensor(center[None], dtype=torch.float32), 8, 0.2, 32, 2.0)
    assert volume.shape == (1, 2, 8, 8, 8)
    peak = np.unravel_index(int(volume[0, 0].argmax()), (8, 8, 8))
    assert peak == (4, 3, 4) and float(volume[0, 0].max()) == pytest.approx(1.0, abs=1e-3)
    assert float(volume[0, 1].max()) == pytest.approx(1.0, abs=1e-3)  # the other views agree: still 1
    assert float(volume[0, 0, 0, 0, 0]) < 1e-3  # far from the keypoint: no ray through it


def test_maps_only_network_learns_the_detectors_bias_and_round_trips(tiny_capture, tiny_frames, tmp_path):
    detections = perfect_detections(tiny_frames, tiny_capture.cameras, shift_m=BIAS_M)
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, TINY_AGREEMENT, detections=detections)
    result = train_mvnet(dataset, TINY_AGREEMENT, budget_s=BY_STEPS_S, checkpoint_dir=tmp_path, max_steps=150,
                         seed=2)
    torch.manual_seed(2)
    trained_mm, untrained_mm = _error_mm(result.model, dataset), _error_mm(MVNet(TINY_AGREEMENT).eval(), dataset)
    assert untrained_mm > 0.8 * 1000 * np.linalg.norm(BIAS_M), untrained_mm
    assert trained_mm < 0.8 * untrained_mm, (trained_mm, untrained_mm)
    model, meta = load_model(result.checkpoint, "mvnet")
    assert model.config == TINY_AGREEMENT and meta["config_digest"] == config_digest(TINY_AGREEMENT)
    np.testing.assert_allclose(_error_mm(model, dataset), trained_mm, atol=1e-4)
    with pytest.raises(CheckpointError):  # another digest: refused
        load_model(result.checkpoint, "mvnet", replace(TINY_AGREEMENT, detector_residual="views"))


def test_the_pose_correction_travels_with_the_weights(tmp_path):
    """detector_pose_correction=True: the pose term is saved with the weights and read back as it was set (float32);
    a network without it reads none, refuses to keep one, and the option needs the offsets."""
    config = replace(TINY_DETECTOR, detector_offsets=True, detector_pose_correction=True)
    assert config_digest(config) != config_digest(replace(config, detector_pose_correction=False))
    rng = np.random.default_rng(0)
    pose = PoseCorrection(rng.normal(0, 0.05, 63), rng.normal(0, 0.1, (63, 63)), rng.normal(0, 0.005, 63),
                          rng.normal(0, 100, (63, 63)), 42)
    offsets = KeypointOffsets(rng.normal(0, 0.005, (21, 3)), np.full(21, 42), pose)
    model = MVNet(config)
    assert model.keypoint_offsets().pose is None  # untrained: nothing learned
    model.set_keypoint_offsets(offsets)
    torch.save(model.state_dict(), tmp_path / "weights.pt")
    loaded = MVNet(config)
    loaded.load_state_dict(torch.load(tmp_path / "weights.pt"))
    read = loaded.keypoint_offsets().pose
    assert read is not None and read.frames_used == 42
    for name in ("mean", "weights", "bias", "leverage"):
        np.testing.assert_allclose(getattr(read, name), getattr(pose, name), rtol=1e-6, atol=1e-6)
    loaded.set_keypoint_offsets(KeypointOffsets(offsets.offsets_m, offsets.frames_used))  # a round with too few labels
    assert loaded.keypoint_offsets().pose is None and not loaded.detector_pose_weights.any()
    plain = MVNet(replace(config, detector_pose_correction=False))
    with pytest.raises(ValueError, match="no detector_pose_correction"):
        plain.set_keypoint_offsets(offsets)
    with pytest.raises(ValueError, match="detector_pose_correction needs detector_offsets"):
        replace(TINY_DETECTOR, detector_pose_correction=True)


def test_learned_keypoint_offsets_move_the_maps_and_travel_with_the_weights(tiny_capture, tiny_frames, tmp_path):
    """detector_offsets=True: the dataset's detections are moved by the offsets (the untrained network triangulates
    the moved points, not the detected ones), the offsets are saved with the weights, and prediction from the raw
    detections applies them as training did."""
    config = replace(TINY_DETECTOR, detector_offsets=True)
    cameras = list(tiny_capture.cameras)
    detections = perfect_detections(tiny_frames, cameras)
    offsets = KeypointOffsets(np.tile([0.03, 0.0, 0.0], (21, 1)), np.full(21, 10))  # 3 cm along every bone
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, config, detections=detections, detector_offsets=offsets)
    truth = np.stack([load_ground_truth(f).keypoints_3d for f in tiny_frames])
    moved = offsets.apply(truth)
    torch.manual_seed(0)
    untrained = MVNet(config).eval()
    untrained.set_keypoint_offsets(offsets)
    pred = predict_from_crops(untrained, dataset.crops, dataset.K_crop, dataset.centers_world, cameras,
                              dataset.view_valid, detector_px=_crop_px(dataset),
                              detector_scores=dataset.detector_scores)
    assert 1000 * np.linalg.norm(pred.keypoints_3d - moved, axis=-1).mean() < 0.2 * 1000 * config.voxel_m
    assert 1000 * np.linalg.norm(pred.keypoints_3d - truth, axis=-1).mean() > 20
    result = train_mvnet(dataset, config, budget_s=BY_STEPS_S, checkpoint_dir=tmp_path, max_steps=2, seed=2)
    model, meta = load_model(result.checkpoint, "mvnet")
    assert meta["config_digest"] == config_digest(config) != config_digest(TINY_DETECTOR)
    np.testing.assert_allclose(model.keypoint_offsets().offsets_m, offsets.offsets_m, atol=1e-8)
    np.testing.assert_array_equal(model.keypoint_offsets().frames_used, offsets.frames_used)
    views = [[load_frame_images(f, cameras)[c.name] for c in cameras] for f in tiny_frames]
    from_raw = predict_keypoints(model, views, cameras, dataset.centers_world, detections=detections)
    from_dataset = predict_from_crops(model, dataset.crops, dataset.K_crop, dataset.centers_world, cameras,
                                      dataset.view_valid, detector_px=_crop_px(dataset),
                                      detector_scores=dataset.detector_scores)
    np.testing.assert_allclose(from_raw.keypoints_3d, from_dataset.keypoints_3d, atol=1e-6)
    assert MVNet(TINY_DETECTOR).keypoint_offsets() is None
    with pytest.raises(ValueError, match="detector_offsets needs"):
        replace(get_config("tiny").mvnet, detector_offsets=True)


def test_readout_window_keeps_the_peak_near_the_lift():
    """window_scores: a volume peaking far from the window's centre is read inside the window (its confidence the
    peak there); no centre (NaN), or a window that holds no voxel, leaves the volume whole."""
    N = 12
    axis = torch.arange(N, dtype=torch.float32)

    def bump(center, height):
        d2 = sum(((axis - c) ** 2).reshape([-1 if i == a else 1 for i in range(3)]) for a, c in enumerate(center))
        return height * torch.exp(-d2 / (2 * 1.5**2))

    volume = torch.maximum(bump((2, 2, 2), 1.0), bump((9, 8, 9), 0.6))[None, None].repeat(1, 3, 1, 1, 1)
    centers = torch.tensor([[[8.6, 8.0, 9.4], [float("nan")] * 3, [40.0, 40.0, 40.0]]])
    grid, conf = refined_argmax(window_scores(volume, centers, radius_voxels=2.5))
    np.testing.assert_allclose(grid[0, 0].numpy(), [9, 8, 9], atol=1e-4)
    assert conf[0, 0].item() == pytest.approx(0.6, abs=1e-3)
    np.testing.assert_allclose(grid[0, 1:].numpy(), [[2, 2, 2], [2, 2, 2]], atol=1e-4)  # whole volume: the far peak
    assert conf[0, 1:].numpy() == pytest.approx([1.0, 1.0], abs=1e-3)
    whole, _ = refined_argmax(volume)
    np.testing.assert_allclose(whole[0, 0].numpy(), [2, 2, 2], atol=1e-4)


def test_readout_window_is_a_prediction_setting_around_the_lifted_keypoints(tiny_capture, tiny_frames):
    """detector_window_m: validated, detector-backed only, not part of the digest (the weights mean the same); the
    prediction stays within the window of the lifted keypoints, from the raw detections and from the dataset alike."""
    assert get_config("cpu-small-detector").mvnet.detector_window_m == DETECTOR_WINDOW_M > 0
    assert paper_only(replace(get_config("tiny"), name="tiny-detector",
                              mvnet=replace(TINY_DETECTOR, detector_window_m=0.04))).mvnet.detector_window_m == 0
    assert config_digest(TINY_DETECTOR) == config_digest(replace(TINY_DETECTOR, detector_window_m=0.04))
    for bad in (-0.01, float("nan"), float("inf"), True, "3cm"):
        with pytest.raises(ValueError, match="detector_window_m must be"):
            replace(TINY_DETECTOR, detector_window_m=bad)
    with pytest.raises(ValueError, match="detector_window_m needs"):
        replace(get_config("tiny").mvnet, detector_window_m=0.03)
    cameras = list(tiny_capture.cameras)
    truth = np.stack([load_ground_truth(f).keypoints_3d for f in tiny_frames])
    # The views' keypoints where the hand is, the lift reported 10 cm off: the maps peak at the truth.
    shift = np.array([0.1, 0.0, 0.0])
    detections = [replace(d, points_world=d.points_world + shift) for d in perfect_detections(tiny_frames, cameras)]
    views = [[load_frame_images(f, cameras)[c.name] for c in cameras] for f in tiny_frames]
    torch.manual_seed(0)
    model = MVNet(TINY_DETECTOR).eval()
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, replace(TINY_DETECTOR, detector_window_m=0.04),
                                  detections=detections)
    centers = dataset.centers_world
    free = predict_keypoints(model, views, cameras, centers, detections=detections)
    assert 1000 * np.linalg.norm(free.keypoints_3d - truth, axis=-1).mean() < 0.2 * 1000 * TINY_DETECTOR.voxel_m
    model.config = replace(TINY_DETECTOR, detector_window_m=0.04)
    windowed = predict_keypoints(model, views, cameras, centers, detections=detections)
    to_lift = np.linalg.norm(windowed.keypoints_3d - (truth + shift), axis=-1)
    assert to_lift.max() <= 0.04 + 0.5 * TINY_DETECTOR.voxel_m
    assert (windowed.confidence < free.confidence).all()  # the peak inside the window is the Gaussian's tail
    np.testing.assert_allclose(dataset.detector_world, truth + shift)
    from_dataset = predict_from_crops(model, dataset.crops, dataset.K_crop, centers, cameras, dataset.view_valid,
                                      detector_px=_crop_px(dataset), detector_scores=dataset.detector_scores,
                                      detector_world=dataset.detector_world)
    np.testing.assert_allclose(from_dataset.keypoints_3d, windowed.keypoints_3d, atol=1e-5)
