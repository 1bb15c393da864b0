"""Training data: augmentation keeps the crop geometry exact, recolouring and backgrounds behave."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from workers.capture.reader import load_frame_images
from workers.nets.configs import get_config
from workers.nets.data import augment_mvnet_batch, build_mvnet_dataset, cut_and_paste, despill, random_background


def test_augmented_crops_match_their_intrinsics(tiny_capture, tiny_frames):
    """A rotated / scaled / shifted crop must be what its new K_crop says: warping the whole image with
    K_new K^-1 reproduces it (the unprojection relies on this)."""
    config = replace(get_config("cpu-small").mvnet, crop_rotation_deg=40.0, crop_scale=0.15, cut_paste_prob=0.0,
                     color_jitter=0.0, train_views=5)
    dataset = build_mvnet_dataset(tiny_capture, tiny_frames, config)
    batch = augment_mvnet_batch(dataset, np.array([0]), config, np.random.default_rng(3))
    cameras = list(tiny_capture.cameras)
    images = load_frame_images(tiny_frames[0], cameras)
    S = config.crop_px
    assert batch["crops"].shape == (1, 5, S, S, 3) and len(set(batch["view_index"][0])) == 5
    for v, c in enumerate(batch["view_index"][0]):
        cam = cameras[c]
        A = batch["K_crop"][0, v].astype(np.float64) @ np.linalg.inv(cam.K)
        expected = cv2.warpAffine(images[cam.name], A[:2], (S, S), flags=cv2.INTER_LINEAR)
        inner = slice(S // 4, 3 * S // 4)  # away from borders the augmentation reflects
        diff = np.abs(expected[inner, inner].astype(float) - batch["crops"][0, v, inner, inner].astype(float))
        assert diff.mean() < 6.0, (c, diff.mean())


def test_despill_and_cut_and_paste():
    rng = np.random.default_rng(0)
    spilled = np.full((8, 8, 3), (115, 119, 83), np.uint8)  # skin with green spill
    clean = despill(spilled)
    assert clean[0, 0, 1] <= (115 + 83) // 2 and clean[0, 0, 0] == 115
    image = np.zeros((32, 32, 3), np.uint8)
    image[:, :] = (40, 200, 60)  # green screen
    image[8:24, 8:24] = (200, 150, 120)  # foreground
    alpha = np.zeros((32, 32), np.uint8)
    alpha[8:24, 8:24] = 255
    out = cut_and_paste(image, alpha, rng, recolor=0.0)
    assert np.abs(out[12:20, 12:20].astype(int) - image[12:20, 12:20].astype(int)).max() <= 1  # foreground kept
    assert not np.array_equal(out[:4, :4], image[:4, :4])  # background replaced
    backgrounds = np.stack([random_background(24, 24, rng) for _ in range(30)])
    assert backgrounds.dtype == np.uint8 and backgrounds.reshape(30, -1).std(axis=1).max() > 5
    assert np.unique(backgrounds.reshape(30, -1).mean(axis=1).round()).size > 10  # varied


def test_networks_of_every_configuration_keep_their_shapes_and_reject_bad_settings():
    import pytest
    import torch

    from workers.nets.handsegnet import HandSegNet
    from workers.nets.mvnet import MVNet

    for name in ("cpu-small", "tiny"):
        config = get_config(name)
        logits = HandSegNet(config.handsegnet).eval()(torch.zeros(2, 50, 61, 3, dtype=torch.uint8))
        assert logits.shape == (2, 50, 61) and logits.dtype == torch.float32  # any size, float32 out (bf16 inside)
        mv = MVNet(config.mvnet).eval()
        S = config.mvnet.crop_px
        features = mv.encode_views(torch.zeros(1, 3, S, S, 3, dtype=torch.uint8))
        assert features.shape == (1, 3, config.mvnet.feature_channels, config.mvnet.feature_px,
                                  config.mvnet.feature_px)
    with pytest.raises(ValueError, match="2D keypoint head"):
        replace(get_config("cpu-small").mvnet, aux_2d_weight=0.0)
    with pytest.raises(ValueError, match="decoder_levels"):
        replace(get_config("cpu-small").mvnet, decoder_levels=3)
    with pytest.raises(ValueError, match="norm"):
        MVNet(replace(get_config("tiny").mvnet, norm="layer"))
