"""Warm starts across bootstrap rounds (init_from, previous_checkpoint) and training crops centred on given
hand masks (build_mvnet_dataset(hand_masks=...))."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from workers.capture.reader import load_ground_truth
from workers.nets.checkpoints import CheckpointError, load_model, previous_checkpoint, round_dir
from workers.nets.configs import get_config
from workers.nets.data import build_handseg_dataset, build_mvnet_dataset, hand_center_from_labels
from workers.nets.train import train_handsegnet, train_mvnet


def _weights(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


def test_mvnet_warm_start_continues_from_the_earlier_round(tiny_capture, tiny_frames, tmp_path):
    config = get_config("tiny")
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, config.mvnet)
    first = train_mvnet(dataset, config, budget_s=60, checkpoint_dir=round_dir(tmp_path, 0), max_steps=3, seed=0)
    assert "init_from" not in first.metadata
    # No step: the warm-started network is exactly the earlier round's.
    same = train_mvnet(dataset, config, budget_s=60, checkpoint_dir=round_dir(tmp_path, 1), max_steps=0, seed=1,
                       init_from=first.checkpoint)
    for key, value in _weights(first.model).items():
        torch.testing.assert_close(same.model.state_dict()[key], value)
    fresh = train_mvnet(dataset, config, budget_s=60, checkpoint_dir=tmp_path / "fresh", max_steps=0, seed=1)
    assert any(not torch.equal(fresh.model.state_dict()[k], v) for k, v in _weights(first.model).items())
    # Training from it records where it came from and the steps accumulated behind the weights.
    second = train_mvnet(dataset, config, budget_s=60, checkpoint_dir=round_dir(tmp_path, 2), max_steps=2, seed=2,
                         init_from=same.checkpoint)
    origin = second.metadata["init_from"]
    assert origin["path"] == str(same.checkpoint) and origin["steps"] == 0
    assert origin["cumulative_steps"] == 3 and second.metadata["steps"] == 2
    _, meta = load_model(second.checkpoint, "mvnet")
    assert meta["init_from"]["path"] == str(same.checkpoint)


def test_warm_start_from_another_architecture_fails_clearly(tiny_capture, tiny_frames, tmp_path):
    config = get_config("tiny")
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, config.mvnet)
    first = train_mvnet(dataset, config, budget_s=60, checkpoint_dir=tmp_path / "a", max_steps=1)
    other = replace(config.mvnet, unet_widths=(8, 8))
    with pytest.raises(CheckpointError, match="does not fit the requested configuration"):
        train_mvnet(dataset, other, budget_s=60, checkpoint_dir=tmp_path / "b", max_steps=1, init_from=first.checkpoint)
    with pytest.raises(CheckpointError, match="not found"):
        train_mvnet(dataset, config, budget_s=60, checkpoint_dir=tmp_path / "c", max_steps=1,
                    init_from=tmp_path / "missing.pt")
    with pytest.raises(CheckpointError, match="not handsegnet"):
        train_handsegnet(build_handseg_dataset(tiny_capture, tiny_frames), config, budget_s=60,
                         checkpoint_dir=tmp_path / "d", max_steps=1, init_from=first.checkpoint)


def test_previous_checkpoint_is_the_latest_earlier_round_of_the_same_architecture(tiny_capture, tiny_frames,
                                                                                  tmp_path):
    config = get_config("tiny")
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, config.mvnet)
    other = replace(config.mvnet, unet_widths=(8, 8))
    assert previous_checkpoint(tmp_path / "none", "mvnet", config.mvnet, 5) is None
    r0 = train_mvnet(dataset, config, budget_s=60, checkpoint_dir=round_dir(tmp_path, 0), max_steps=1).checkpoint
    train_mvnet(dataset, other, budget_s=60, checkpoint_dir=round_dir(tmp_path, 2), max_steps=1)
    r3 = train_mvnet(dataset, config, budget_s=60, checkpoint_dir=round_dir(tmp_path, 3), max_steps=1).checkpoint
    (round_dir(tmp_path, 1) / "mvnet.json").parent.mkdir(parents=True)
    (round_dir(tmp_path, 1) / "mvnet.json").write_text("{broken")
    assert previous_checkpoint(tmp_path, "mvnet", config.mvnet, 1) == r0
    assert previous_checkpoint(tmp_path, "mvnet", config.mvnet, 3) == r0  # round 2 is another architecture
    assert previous_checkpoint(tmp_path, "mvnet", config.mvnet, 4) == r3
    assert previous_checkpoint(tmp_path, "mvnet", other, 3) == round_dir(tmp_path, 2) / "mvnet.pt"
    assert previous_checkpoint(tmp_path, "mvnet", config.mvnet, 0) is None
    assert previous_checkpoint(tmp_path, "handsegnet", config.handsegnet, 4) is None


def test_training_crops_centred_on_given_hand_masks(tiny_capture, tiny_frames):
    config = get_config("tiny").mvnet
    cameras = list(tiny_capture.cameras)
    truth = [load_ground_truth(f) for f in tiny_frames]
    masks = [{c.name: gt.hand_masks[c.name] for c in cameras} for gt in truth]
    labels = np.stack([gt.keypoints_3d for gt in truth]).astype(np.float32)
    by_masks = build_mvnet_dataset(tiny_capture, tiny_frames, config, keypoints_3d=labels, hand_masks=masks)
    expected = [hand_center_from_labels([m[c.name] for c in cameras], kp, cameras)
                for m, kp in zip(masks, labels, strict=True)]
    np.testing.assert_allclose(by_masks.centers_world, np.stack(expected), atol=1e-6)
    # Without masks the centre is the mean keypoint; the mask centre lies elsewhere (the palm, not the fingers).
    no_masks = build_mvnet_dataset(tiny_capture, tiny_frames, config, keypoints_3d=labels, hand_masks=[None, None])
    np.testing.assert_allclose(no_masks.centers_world, labels.mean(axis=1), atol=1e-6)
    assert np.linalg.norm(by_masks.centers_world - no_masks.centers_world, axis=1).max() > 1e-3
    with pytest.raises(ValueError, match="hand_masks has 1 entries for 2 frames"):
        build_mvnet_dataset(tiny_capture, tiny_frames, config, hand_masks=masks[:1])
    partial = [{k: v for k, v in m.items() if k != cameras[2].name} for m in masks]
    with pytest.raises(ValueError, match=r"lack camera\(s\) \['cam2'\]"):
        build_mvnet_dataset(tiny_capture, tiny_frames, config, hand_masks=partial)
