"""MVNet (paper Fig. 4): a 2D CNN shared across views -> unprojection into a voxel grid around the hand ->
average over views -> a 3D U-Net -> one score volume per keypoint.

The module only holds parameters; the steps are `encode_views`, `unproject_features` (unproject.py) and
`decode_volume`, and the read-out lives in losses.py.
"""

from __future__ import annotations

import torch
from torch import nn

from workers.handmodel.keypoints import NUM_KEYPOINTS
from workers.nets.configs import MVNetConfig
from workers.nets.unproject import unproject_features

# Per-channel normalisation of uint8 RGB input (ImageNet statistics, a neutral choice).
RGB_MEAN = (0.485, 0.456, 0.406)
RGB_STD = (0.229, 0.224, 0.225)


def _groups(channels: int) -> int:
    return max(1, min(8, channels // 4))


def conv_block(cin: int, cout: int, dims: int) -> nn.Sequential:
    """3x3(x3) convolution, group norm, ReLU."""
    conv = nn.Conv2d if dims == 2 else nn.Conv3d
    return nn.Sequential(conv(cin, cout, 3, padding=1, bias=False), nn.GroupNorm(_groups(cout), cout),
                         nn.ReLU(inplace=True))


class FeatureEncoder2d(nn.Module):
    """Crops (M, 3, S, S) float -> features (M, F, S / 2^(L-1), S / 2^(L-1)); L = len(widths)."""

    def __init__(self, widths: tuple[int, ...], convs_per_stage: int, out_channels: int) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        cin = 3
        for level, width in enumerate(widths):
            if level:
                layers.append(nn.MaxPool2d(2))
            for _ in range(convs_per_stage):
                layers.append(conv_block(cin, width, 2))
                cin = width
        layers.append(nn.Conv2d(cin, out_channels, 1))
        self.body = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.body(x)


class UNet3d(nn.Module):
    """(B, F, N, N, N) -> (B, out, N, N, N): encoder-decoder with skip connections (Ronneberger et al.)."""

    def __init__(self, in_channels: int, widths: tuple[int, ...], out_channels: int) -> None:
        super().__init__()
        self.down = nn.ModuleList()
        cin = in_channels
        for level, width in enumerate(widths):
            convs = [conv_block(cin, width, 3)] + ([conv_block(width, width, 3)] if level else [])
            self.down.append(nn.Sequential(*convs))
            cin = width
        self.pool = nn.MaxPool3d(2)
        self.up = nn.ModuleList()
        self.merge = nn.ModuleList()
        for level in range(len(widths) - 2, -1, -1):
            self.up.append(nn.ConvTranspose3d(widths[level + 1], widths[level], 2, stride=2))
            self.merge.append(conv_block(2 * widths[level], widths[level], 3))
        self.head = nn.Conv3d(widths[0], out_channels, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for level, block in enumerate(self.down):
            if level:
                x = self.pool(x)
            x = block(x)
            skips.append(x)
        for up, merge, skip in zip(self.up, self.merge, reversed(skips[:-1]), strict=True):
            x = merge(torch.cat([up(x), skip], dim=1))
        return self.head(x)


class MVNet(nn.Module):
    """Multi-view 3D keypoint network of the configuration it was built with (`self.config`)."""

    def __init__(self, config: MVNetConfig, num_keypoints: int = NUM_KEYPOINTS) -> None:
        super().__init__()
        self.config = config
        self.encoder = FeatureEncoder2d(config.backbone_widths, config.convs_per_stage, config.feature_channels)
        self.unet = UNet3d(config.feature_channels, config.unet_widths, num_keypoints)
        self.register_buffer("rgb_mean", torch.tensor(RGB_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("rgb_std", torch.tensor(RGB_STD).view(1, 3, 1, 1), persistent=False)

    def encode_views(self, crops: torch.Tensor) -> torch.Tensor:
        """crops (B, C, S, S, 3) uint8 or float in [0, 1] -> features (B, C, F, h, h)."""
        B, C, S = crops.shape[:3]
        if crops.shape[2:] != (self.config.crop_px, self.config.crop_px, 3):
            raise ValueError(f"crops must be (B, C, {self.config.crop_px}, {self.config.crop_px}, 3) for this "
                             f"configuration, got {tuple(crops.shape)}")
        x = crops.reshape(B * C, S, S, 3).permute(0, 3, 1, 2)
        x = x.float() / 255.0 if crops.dtype == torch.uint8 else x.float()
        features = self.encoder((x - self.rgb_mean) / self.rgb_std)
        return features.reshape(B, C, *features.shape[1:])

    def forward(self, crops: torch.Tensor, K_crop: torch.Tensor, dist: torch.Tensor, R: torch.Tensor,
                t: torch.Tensor, center_world: torch.Tensor, view_valid: torch.Tensor | None = None) -> torch.Tensor:
        """Score volumes of one batch of frames.

        Args:
            crops: (B, C, S, S, 3) hand crops, uint8 RGB (or float in [0, 1]).
            K_crop: (B, C, 3, 3) crop intrinsics, pixels of the crop.
            dist: (C, 5); R: (C, 3, 3); t: (C, 3) the rig, world -> camera, metres.
            center_world: (B, 3) grid centres, metres, world frame.
            view_valid: (B, C) bool, views to use (default all).
        Returns:
            (B, K, N, N, N) score volumes, index (i, j, l) along world (x, y, z).
        """
        cfg = self.config
        features = self.encode_views(crops)
        volume = unproject_features(features, K_crop, dist, R, t, center_world, cfg.grid_size, cfg.grid_side_m,
                                    cfg.crop_px, view_valid)
        return self.unet(volume)
