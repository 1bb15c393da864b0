"""HandSegNet (paper ref. hand3d, Zimmermann & Brox 2017): per-pixel hand probability of one view.

A small fully convolutional encoder-decoder (2D U-Net); it trains on patches and runs on whole images of
any size (padded to a multiple of its stride). Metric: intersection over union (`mask_iou`).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as nnf
from torch import nn

from workers.nets.blocks import conv_block, max_pool_2x2, unet_pass
from workers.nets.configs import HandSegNetConfig
from workers.nets.mvnet import RGB_MEAN, RGB_STD, autocast_bf16


class HandSegNet(nn.Module):
    """images (B, H, W, 3) uint8 RGB -> hand logits (B, H, W).

    A 2D U-Net over `widths`. With `stem_stride` 2 the first convolution halves the resolution (the costly
    full-resolution levels are skipped) and a light full-resolution head sees the upsampled features next
    to the image itself, so the mask keeps pixel-accurate edges (IoU is very sensitive to a one-pixel rim
    on a hand of ~1,500 pixels).
    """

    def __init__(self, config: HandSegNetConfig) -> None:
        super().__init__()
        self.config = config
        widths, norm = config.widths, config.norm
        self.down = nn.ModuleList()
        cin = 3
        for level, width in enumerate(widths):
            stride = config.stem_stride if level == 0 else 1
            self.down.append(nn.Sequential(conv_block(cin, width, 2, stride, norm),
                                           conv_block(width, width, 2, norm=norm)))
            cin = width
        self.up = nn.ModuleList()
        self.merge = nn.ModuleList()
        for level in range(len(widths) - 2, -1, -1):
            self.up.append(nn.ConvTranspose2d(widths[level + 1], widths[level], 2, stride=2))
            self.merge.append(nn.Sequential(conv_block(2 * widths[level], widths[level], 2, norm=norm),
                                            conv_block(widths[level], widths[level], 2, norm=norm)))
        if config.stem_stride > 1:
            head = max(8, widths[0] // 2)
            self.full_res = nn.Sequential(conv_block(widths[0] + 3, head, 2, norm=norm), nn.Conv2d(head, 1, 1))
            self.head = None
        else:
            self.full_res = None
            self.head = nn.Conv2d(widths[0], 1, 1)
        self.register_buffer("rgb_mean", torch.tensor(RGB_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("rgb_std", torch.tensor(RGB_STD).view(1, 3, 1, 1), persistent=False)

    @property
    def stride(self) -> int:
        return self.config.stem_stride * 2 ** (len(self.config.widths) - 1)

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
        rgb = x.contiguous(memory_format=torch.channels_last)
        with autocast_bf16(rgb, self.config.bf16):
            logits = self._forward(rgb)
        return logits.float()[:, 0, :H, :W]

    def _forward(self, rgb: torch.Tensor) -> torch.Tensor:
        x = unet_pass(rgb, self.down, self.up, self.merge, max_pool_2x2)
        if self.full_res is not None:
            x = nnf.interpolate(x, size=rgb.shape[-2:], mode="bilinear", align_corners=False)
            logits = self.full_res(torch.cat([x, rgb], dim=1))
        else:
            logits = self.head(x)
        return logits


def mask_iou(predicted: np.ndarray, target: np.ndarray) -> float:
    """Intersection over union of two boolean masks (any equal shapes); 1.0 when both are empty."""
    predicted, target = np.asarray(predicted, bool), np.asarray(target, bool)
    if predicted.shape != target.shape:
        raise ValueError(f"mask shapes differ: {predicted.shape} vs {target.shape}")
    union = np.logical_or(predicted, target).sum()
    return 1.0 if union == 0 else float(np.logical_and(predicted, target).sum() / union)
