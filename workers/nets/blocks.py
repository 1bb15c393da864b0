"""Building blocks shared by MVNet's 2D encoder, its 3D U-Net and HandSegNet."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
import torch.nn.functional as nnf
from torch import nn


def max_pool_2x2(x: torch.Tensor) -> torch.Tensor:
    return nnf.max_pool2d(x, 2)


def _groups(channels: int) -> int:
    return max(1, min(8, channels // 4))


def conv_block(cin: int, cout: int, dims: int, stride: int = 1, norm: str = "group") -> nn.Sequential:
    """3x3(x3) convolution, normalisation ("group" or "batch"), ReLU."""
    conv = nn.Conv2d if dims == 2 else nn.Conv3d
    if norm == "batch":
        layer: nn.Module = nn.BatchNorm2d(cout) if dims == 2 else nn.BatchNorm3d(cout)
    elif norm == "group":
        layer = nn.GroupNorm(_groups(cout), cout)
    else:
        raise ValueError(f"norm must be 'group' or 'batch', got {norm!r}")
    return nn.Sequential(conv(cin, cout, 3, stride=stride, padding=1, bias=False), layer, nn.ReLU(inplace=True))


def unet_pass(x: torch.Tensor, down: Sequence[nn.Module], up: Sequence[nn.Module], merge: Sequence[nn.Module],
              pool: Callable[[torch.Tensor], torch.Tensor]) -> torch.Tensor:
    """The encoder-decoder pass of a U-Net (Ronneberger et al.), 2D or 3D: the encoder's levels with `pool`
    between them, then one decoder level per `up` (deepest first), each upsampling and merging the encoder's
    features of the same resolution. With fewer `up` than encoder levels - 1 the output stays coarser."""
    skips = []
    for level, block in enumerate(down):
        if level:
            x = pool(x)
        x = block(x)
        skips.append(x)
    for upsample, fuse, skip in zip(up, merge, reversed(skips[:-1]), strict=False):
        x = fuse(torch.cat([upsample(x), skip], dim=1))
    return x
