"""HandSegNet (paper ref. hand3d, Zimmermann & Brox 2017): per-pixel hand probability of one view.

A small fully convolutional encoder-decoder (2D U-Net); it trains on patches and runs on whole images of
any size (padded to a multiple of its stride). Metric: intersection over union (`mask_iou`).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as nnf
from torch import nn

from workers.nets.configs import HandSegNetConfig
from workers.nets.mvnet import RGB_MEAN, RGB_STD, conv_block


class HandSegNet(nn.Module):
    """images (B, H, W, 3) uint8 RGB -> hand logits (B, H, W)."""

    def __init__(self, config: HandSegNetConfig) -> None:
        super().__init__()
        self.config = config
        widths = config.widths
        self.down = nn.ModuleList()
        cin = 3
        for width in widths:
            self.down.append(nn.Sequential(conv_block(cin, width, 2), conv_block(width, width, 2)))
            cin = width
        self.up = nn.ModuleList()
        self.merge = nn.ModuleList()
        for level in range(len(widths) - 2, -1, -1):
            self.up.append(nn.ConvTranspose2d(widths[level + 1], widths[level], 2, stride=2))
            self.merge.append(nn.Sequential(conv_block(2 * widths[level], widths[level], 2),
                                            conv_block(widths[level], widths[level], 2)))
        self.head = nn.Conv2d(widths[0], 1, 1)
        self.register_buffer("rgb_mean", torch.tensor(RGB_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("rgb_std", torch.tensor(RGB_STD).view(1, 3, 1, 1), persistent=False)

    @property
    def stride(self) -> int:
        return 2 ** (len(self.config.widths) - 1)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """images (B, H, W, 3) uint8 (or float in [0, 1]) -> logits (B, H, W)."""
        if images.ndim != 4 or images.shape[-1] != 3:
            raise ValueError(f"images must be (B, H, W, 3) RGB, got {tuple(images.shape)}")
        H, W = images.shape[1:3]
        x = images.permute(0, 3, 1, 2)
        x = x.float() / 255.0 if images.dtype == torch.uint8 else x.float()
        x = (x - self.rgb_mean) / self.rgb_std
        s = self.stride
        pad_h, pad_w = (-H) % s, (-W) % s
        if pad_h or pad_w:
            x = nnf.pad(x, (0, pad_w, 0, pad_h), mode="replicate")
        skips = []
        for level, block in enumerate(self.down):
            if level:
                x = nnf.max_pool2d(x, 2)
            x = block(x)
            skips.append(x)
        for up, merge, skip in zip(self.up, self.merge, reversed(skips[:-1]), strict=True):
            x = merge(torch.cat([up(x), skip], dim=1))
        return self.head(x)[:, 0, :H, :W]


def mask_iou(predicted: np.ndarray, target: np.ndarray) -> float:
    """Intersection over union of two boolean masks (any equal shapes); 1.0 when both are empty."""
    predicted, target = np.asarray(predicted, bool), np.asarray(target, bool)
    if predicted.shape != target.shape:
        raise ValueError(f"mask shapes differ: {predicted.shape} vs {target.shape}")
    union = np.logical_or(predicted, target).sum()
    return 1.0 if union == 0 else float(np.logical_and(predicted, target).sum() / union)
