"""MVNet and HandSegNet learn (overfit a few frames), checkpoints round-trip and resume, bad inputs fail
clearly."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from tests.support.training import BY_STEPS_S
from workers.capture.reader import load_frame_images, load_ground_truth
from workers.nets.checkpoints import CheckpointError, load_model, round_dir
from workers.nets.configs import get_config
from workers.nets.data import build_handseg_dataset, build_mvnet_dataset
from workers.nets.handsegnet import mask_iou
from workers.nets.predict import predict_frames, predict_from_crops, predict_keypoints, predict_masks
from workers.nets.train import train_handsegnet, train_mvnet

# cpu-small's architecture without augmentation: the network must memorise two frames.
OVERFIT = replace(get_config("cpu-small").mvnet, center_jitter_m=0.0, cut_paste_prob=0.0, color_jitter=0.0,
                  crop_rotation_deg=0.0, crop_scale=0.0, train_views=0, batch_frames=2)
# The overfit fixture (1,000 steps, about a minute on a quiet core) ran past 600 s on a machine loaded four-fold.
pytestmark = pytest.mark.timeout(1800)


@pytest.fixture(scope="module")
def overfit(tiny_capture, tiny_frames, tmp_path_factory):
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, OVERFIT)
    ckpt = round_dir(tmp_path_factory.mktemp("ckpt"), 0)
    # ~1000 steps bring two frames to ~10 mm (400 left them at ~33 mm); about a minute on one core.
    result = train_mvnet(dataset, OVERFIT, budget_s=BY_STEPS_S, checkpoint_dir=ckpt, max_steps=1000, seed=1)
    return dataset, result


def test_mvnet_overfits_two_frames(overfit):
    dataset, result = overfit
    pred = predict_from_crops(result.model, dataset.crops, dataset.K_crop, dataset.centers_world, dataset.cameras,
                              dataset.view_valid)
    error_mm = 1000 * np.linalg.norm(pred.keypoints_3d - dataset.keypoints_3d, axis=-1)
    assert pred.keypoints_3d.shape == (2, 21, 3) and pred.confidence.shape == (2, 21)
    assert error_mm.mean() < 0.8 * 1000 * OVERFIT.voxel_m, error_mm.mean()  # below a voxel (25 mm)
    assert np.all(pred.sample_confidence > 0.5)
    np.testing.assert_allclose(pred.sample_confidence, pred.confidence.mean(axis=1))


def test_checkpoint_round_trip(overfit, tiny_frames):
    dataset, result = overfit
    assert result.checkpoint.parent.name == "round-000"
    model, meta = load_model(result.checkpoint, "mvnet")
    assert meta["training_samples"] == list(dataset.sample_ids) and meta["seed"] == 1
    assert meta["steps"] == 1000 and meta["config"]["grid_size"] == OVERFIT.grid_size
    assert json.loads(result.checkpoint.with_suffix(".json").read_text())["steps"] == 1000
    a = predict_from_crops(result.model, dataset.crops, dataset.K_crop, dataset.centers_world, dataset.cameras)
    b = predict_from_crops(model, dataset.crops, dataset.K_crop, dataset.centers_world, dataset.cameras)
    np.testing.assert_allclose(a.keypoints_3d, b.keypoints_3d, atol=1e-6)


def test_checkpoint_of_another_configuration_fails(overfit, tmp_path):
    _, result = overfit
    with pytest.raises(CheckpointError, match="does not fit the requested configuration"):
        load_model(result.checkpoint, "mvnet", get_config("tiny").mvnet)
    with pytest.raises(CheckpointError, match="does not fit"):
        load_model(result.checkpoint, "mvnet", replace(OVERFIT, loss="softargmax"))
    with pytest.raises(CheckpointError, match="not handsegnet"):
        load_model(result.checkpoint, "handsegnet")
    with pytest.raises(CheckpointError, match="not found"):
        load_model(tmp_path / "missing.pt", "mvnet")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="unreadable"):
        load_model(tmp_path / "junk.pt", "mvnet")


def test_training_resumes_from_the_partial_checkpoint(tiny_capture, tiny_frames, tmp_path):
    config = get_config("tiny")
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, config.mvnet)
    first = train_mvnet(dataset, config, budget_s=60, checkpoint_dir=tmp_path, max_steps=3)
    assert first.metadata["steps"] == 3 and (tmp_path / "mvnet.partial.pt").is_file()
    second = train_mvnet(dataset, config, budget_s=60, checkpoint_dir=tmp_path, max_steps=5)
    assert second.metadata["steps"] == 5
    assert second.metadata["train_seconds"] >= first.metadata["train_seconds"]
    fresh = train_mvnet(dataset, config, budget_s=60, checkpoint_dir=tmp_path, max_steps=2, resume=False)
    assert fresh.metadata["steps"] == 2
    with pytest.raises(CheckpointError, match="does not fit"):
        train_mvnet(dataset, replace(config.mvnet, grid_size=8, unet_widths=(8, 16)), budget_s=60,
                    checkpoint_dir=tmp_path, max_steps=1)


def test_bad_inputs_fail_clearly(overfit, tiny_capture, tiny_frames):
    dataset, result = overfit
    cameras = list(tiny_capture.cameras)
    views = load_frame_images(tiny_frames[0], cameras)
    center = dataset.centers_world[:1]
    missing = {k: v for k, v in views.items() if k != cameras[3].name}
    with pytest.raises(ValueError, match=r"missing view.*cam3"):
        predict_keypoints(result.model, [missing], cameras, center)
    wrong = dict(views)
    wrong[cameras[1].name] = np.zeros((50, 60, 3), np.uint8)
    with pytest.raises(ValueError, match="60x50 px, the calibration says"):
        predict_keypoints(result.model, [wrong], cameras, center)
    with pytest.raises(ValueError, match="centers_world"):
        predict_keypoints(result.model, [views], cameras, np.zeros((2, 3)))
    with pytest.raises(ValueError, match="crops must be"):
        result.model.encode_views(torch.zeros(1, 8, 16, 16, 3, dtype=torch.uint8))
    with pytest.raises(ValueError, match="do not match the configuration"):
        train_mvnet(dataset, replace(OVERFIT, crop_px=OVERFIT.crop_px // 2), budget_s=1,
                    checkpoint_dir="/nonexistent")


def test_handsegnet_learns_and_predicts_masks(tiny_capture, tiny_frames, tmp_path):
    config = replace(get_config("tiny").handsegnet, crop_px=48, batch_size=8, lr=5e-3, cut_paste_prob=0.0,
                     color_jitter=0.0)
    dataset = build_handseg_dataset(tiny_capture, tiny_frames)
    assert len(dataset) == 8 * len(tiny_frames)
    result = train_handsegnet(dataset, config, budget_s=BY_STEPS_S, checkpoint_dir=tmp_path, max_steps=400)
    cameras = list(tiny_capture.cameras)
    views = load_frame_images(tiny_frames[0], cameras)
    masks = predict_masks(result.model, views, cameras)
    assert len(masks.probabilities) == 8 and masks.location is not None
    gt = load_ground_truth(tiny_frames[0])
    ious = [mask_iou(p > 0.5, gt.hand_masks[c.name]) for p, c in zip(masks.probabilities, cameras, strict=True)]
    assert all(p.shape == (c.height, c.width) and p.dtype == np.float32
               for p, c in zip(masks.probabilities, cameras, strict=True))
    assert np.mean(ious) > 0.5, ious
    _, meta = load_model(result.checkpoint, "handsegnet")
    assert meta["kind"] == "handsegnet" and meta["num_training_samples"] == len(dataset)


def test_predict_frames_end_to_end_with_chroma_masks(overfit, tiny_capture, tiny_frames):
    _, result = overfit
    green = [f for f in tiny_frames if f.mask_paths]  # the training (green-screen) sequence
    out = predict_frames(result.model, green, list(tiny_capture.cameras))
    assert out.keypoints.keypoints_3d.shape == (len(green), 21, 3)
    assert all(loc is not None for loc in out.locations)
    assert np.isfinite(out.keypoints.keypoints_3d).all()
