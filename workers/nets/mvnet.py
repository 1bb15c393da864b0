"""MVNet (paper Fig. 4): a 2D CNN shared across views -> unprojection into a voxel grid around the hand ->
average over views -> a 3D U-Net -> one score volume per keypoint.

The module only holds parameters; the steps are `encode_views`, `unproject_features` (unproject.py) and
`decode_volume`, and the read-out lives in losses.py.
"""

from __future__ import annotations

import functools

import numpy as np
import torch
from torch import nn

from workers.detector.keypoint_offsets import KeypointOffsets, PoseCorrection
from workers.handmodel.keypoints import NUM_KEYPOINTS
from workers.nets.blocks import conv_block, max_pool_2x2, unet_pass
from workers.nets.configs import MVNetConfig
from workers.nets.keypoint_maps import likelihood_volume, render_keypoint_maps
from workers.nets.losses import peak_normalised
from workers.nets.unproject import unproject_features

# Per-channel normalisation of uint8 RGB input (ImageNet statistics, a neutral choice).
RGB_MEAN = (0.485, 0.456, 0.406)
RGB_STD = (0.229, 0.224, 0.225)


@functools.cache
def native_bf16(device_type: str) -> bool:
    """Whether `device_type` computes bfloat16 convolutions natively: CUDA with bf16 support, or a CPU with
    AVX512-BF16 / AMX (oneDNN). Elsewhere (e.g. AVX2-only CPUs) bfloat16 is emulated, ~8x slower than float32
    (measured: MVNet cpu-small steps 2.65 s vs 0.34 s on an AVX2 EPYC), so `bf16` configs fall back to float32."""
    if device_type == "cuda":
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported()
    if device_type == "cpu":
        return bool(torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported())
    return False


def autocast_bf16(x: torch.Tensor, enabled: bool) -> torch.autocast:
    """bfloat16 autocast on x's device when enabled and native there (`native_bf16`; convolutions 2-3x faster
    on CPUs with AMX / AVX512-BF16); normalisation, losses and the unprojection stay float32."""
    return torch.autocast(device_type=x.device.type, dtype=torch.bfloat16,
                          enabled=enabled and native_bf16(x.device.type))


class FeatureEncoder2d(nn.Module):
    """Crops (M, 3, S, S) float -> features (M, F, S / 2^(L-1-D), same); L = len(widths), D = decoder_levels.

    Stages of `convs_per_stage` 3x3 convolutions with a 2x max-pool between stages; with D > 0 the deepest
    stage is upsampled D times (transposed convolution, skip connection from the encoder, one 3x3
    convolution), so a small map at the output still sees the whole hand (the receptive field of the
    deepest stage) without paying for deep stages at full resolution.
    """

    def __init__(self, widths: tuple[int, ...], convs_per_stage: int, out_channels: int,
                 decoder_levels: int = 0, stem_stride: int = 1, norm: str = "group") -> None:
        super().__init__()
        if not 0 <= decoder_levels < len(widths):
            raise ValueError(f"decoder_levels must be in 0..{len(widths) - 1}, got {decoder_levels}")
        self.stages = nn.ModuleList()
        cin = 3
        for level, width in enumerate(widths):
            convs = []
            for k in range(convs_per_stage):
                stride = stem_stride if level == 0 and k == 0 else 1
                convs.append(conv_block(cin, width, 2, stride, norm))
                cin = width
            self.stages.append(nn.Sequential(*convs))
        self.up = nn.ModuleList()
        self.merge = nn.ModuleList()
        for level in range(len(widths) - 2, len(widths) - 2 - decoder_levels, -1):
            self.up.append(nn.ConvTranspose2d(cin, widths[level], 2, stride=2))
            self.merge.append(conv_block(2 * widths[level], widths[level], 2, norm=norm))
            cin = widths[level]
        self.out = nn.Conv2d(cin, out_channels, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out(unet_pass(x, self.stages, self.up, self.merge, max_pool_2x2))


class UNet3d(nn.Module):
    """(B, F, N, N, N) -> (B, out, N, N, N): encoder-decoder with skip connections (Ronneberger et al.)."""

    def __init__(self, in_channels: int, widths: tuple[int, ...], out_channels: int, norm: str = "group") -> None:
        super().__init__()
        self.down = nn.ModuleList()
        cin = in_channels
        for level, width in enumerate(widths):
            convs = [conv_block(cin, width, 3, norm=norm)] + ([conv_block(width, width, 3, norm=norm)] if level else [])
            self.down.append(nn.Sequential(*convs))
            cin = width
        self.pool = nn.MaxPool3d(2)
        self.up = nn.ModuleList()
        self.merge = nn.ModuleList()
        for level in range(len(widths) - 2, -1, -1):
            self.up.append(nn.ConvTranspose3d(widths[level + 1], widths[level], 2, stride=2))
            self.merge.append(conv_block(2 * widths[level], widths[level], 3, norm=norm))
        self.head = nn.Conv3d(widths[0], out_channels, 1)

    def forward(self, x: torch.Tensor, bf16: bool = False) -> torch.Tensor:
        """x (B, F, N, N, N) float32 -> (B, out, N, N, N) float32 (bf16 = convolutions in bfloat16)."""
        x = x.contiguous(memory_format=torch.channels_last_3d)
        with autocast_bf16(x, bf16):
            return self._forward(x).float().contiguous()

    def _forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(unet_pass(x, self.down, self.up, self.merge, self.pool))


def detector_weight_sum(scores: torch.Tensor, view_valid: torch.Tensor | None, floor: float = 1e-3) -> torch.Tensor:
    """scores (B, C, K) the detector's map weights (NaN = 0), view_valid (B, C) -> (B, K) their sum over the valid
    views, at least `floor` (a keypoint no view detected then has a zero residual, not a division by zero)."""
    w = torch.nan_to_num(scores.float(), nan=0.0)
    if view_valid is not None:
        w = w * view_valid[..., None].to(w.dtype)
    return w.sum(dim=1).clamp(min=floor)


class MVNet(nn.Module):
    """Multi-view 3D keypoint network of the configuration it was built with (`self.config`)."""

    def __init__(self, config: MVNetConfig, num_keypoints: int = NUM_KEYPOINTS) -> None:
        super().__init__()
        self.config = config
        # No 2D CNN where the U-Net sees the detector's maps alone (unet_image_features=False).
        self.encoder = FeatureEncoder2d(config.backbone_widths, config.convs_per_stage, config.feature_channels,
                                        config.decoder_levels, config.stem_stride, config.norm) \
            if config.unet_image_features else None
        # Optional 2D keypoint heads on the shared features (deep supervision, see losses.heatmap_2d_loss).
        self.head_2d = nn.Conv2d(config.feature_channels, num_keypoints, 1) if config.aux_2d_weight > 0 else None
        # Detector-backed: the U-Net sees the unprojected detector maps beside the image features (or alone).
        unet_in = (config.feature_channels if config.unet_image_features else 0) + \
            (num_keypoints if config.heatmap_source == "detector" else 0)
        self.unet = UNet3d(unet_in, config.unet_widths, num_keypoints, config.norm)
        if config.heatmap_source == "detector":
            # The untrained network's score volumes are the detector's unprojected maps (a triangulation); the
            # U-Net's correction starts at zero and is learned from the labels.
            nn.init.zeros_(self.unet.head.weight)
            nn.init.zeros_(self.unet.head.bias)
        if config.detector_offsets:
            # What training learned of the detector's keypoint convention (keypoint_offsets.KeypointOffsets.offsets_m,
            # (K, 3) metres in each keypoint's bone frame): saved with the weights, applied to the detections
            # before they become maps (predict.predict_keypoints, data.build_mvnet_dataset). float32: every device
            # has it (MPS has no float64), and 1e-7 m is far below what the detector resolves.
            self.register_buffer("detector_offsets_m", torch.zeros(num_keypoints, 3, dtype=torch.float32))
            self.register_buffer("detector_offsets_frames", torch.zeros(num_keypoints, dtype=torch.int64))
        if config.detector_pose_correction:  # keypoint_offsets.PoseCorrection, float32 as above; 0 frames: none
            flat = 3 * num_keypoints
            self.register_buffer("detector_pose_mean", torch.zeros(flat, dtype=torch.float32))
            self.register_buffer("detector_pose_weights", torch.zeros(flat, flat, dtype=torch.float32))
            self.register_buffer("detector_pose_bias", torch.zeros(flat, dtype=torch.float32))
            self.register_buffer("detector_pose_leverage", torch.zeros(flat, flat, dtype=torch.float32))
            self.register_buffer("detector_pose_frames", torch.zeros((), dtype=torch.int64))
        self.register_buffer("rgb_mean", torch.tensor(RGB_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("rgb_std", torch.tensor(RGB_STD).view(1, 3, 1, 1), persistent=False)

    def keypoint_offsets(self) -> KeypointOffsets | None:
        """The detector keypoint offsets this network was trained with (None where its configuration has none)."""
        if not self.config.detector_offsets:
            return None
        pose = None
        if self.config.detector_pose_correction and int(self.detector_pose_frames) > 0:
            pose = PoseCorrection(*(b.detach().cpu().numpy().astype(np.float64) for b in
                                    (self.detector_pose_mean, self.detector_pose_weights, self.detector_pose_bias,
                                     self.detector_pose_leverage)), frames_used=int(self.detector_pose_frames))
        return KeypointOffsets(self.detector_offsets_m.detach().cpu().numpy().astype(np.float64),
                               self.detector_offsets_frames.detach().cpu().numpy().astype(np.int64), pose)

    def set_keypoint_offsets(self, offsets: KeypointOffsets | None) -> None:
        """Record the offsets the training data was corrected with (None: no correction)."""
        offsets = offsets or KeypointOffsets.none()
        self.detector_offsets_m.copy_(torch.as_tensor(offsets.offsets_m, dtype=torch.float32))
        self.detector_offsets_frames.copy_(torch.as_tensor(offsets.frames_used, dtype=torch.int64))
        if self.config.detector_pose_correction:
            pose = offsets.pose
            for name in ("mean", "weights", "bias", "leverage"):
                buffer = getattr(self, f"detector_pose_{name}")
                if pose is None:
                    buffer.zero_()
                else:
                    buffer.copy_(torch.as_tensor(getattr(pose, name), dtype=torch.float32))
            self.detector_pose_frames.fill_(0 if pose is None else pose.frames_used)
        elif offsets.pose is not None:
            raise ValueError("these offsets have a pose correction but the configuration has no "
                             "detector_pose_correction to keep it")

    def encode_views(self, crops: torch.Tensor) -> torch.Tensor:
        """crops (B, C, S, S, 3) uint8 or float in [0, 1] -> features (B, C, F, h, h); F = 0 (an empty tensor)
        where the configuration has no 2D CNN (unet_image_features=False)."""
        B, C, S = crops.shape[:3]
        if crops.shape[2:] != (self.config.crop_px, self.config.crop_px, 3):
            raise ValueError(f"crops must be (B, C, {self.config.crop_px}, {self.config.crop_px}, 3) for this "
                             f"configuration, got {tuple(crops.shape)}")
        if self.encoder is None:
            h = self.config.feature_px
            return torch.zeros((B, C, 0, h, h), device=crops.device)
        x = crops.reshape(B * C, S, S, 3).permute(0, 3, 1, 2)  # a channels-last view: what oneDNN prefers
        x = x.float() / 255.0 if crops.dtype == torch.uint8 else x.float()
        x = ((x - self.rgb_mean) / self.rgb_std).contiguous(memory_format=torch.channels_last)
        with autocast_bf16(x, self.config.bf16):
            features = self.encoder(x)
        features = features.float().contiguous()
        return features.reshape(B, C, *features.shape[1:])

    def heatmaps_2d(self, features: torch.Tensor) -> torch.Tensor:
        """features (B, C, F, h, h) -> 2D keypoint score maps (B, C, K, h, h) of the auxiliary head."""
        if self.head_2d is None:
            raise ValueError("this configuration has no 2D keypoint head (aux_2d_weight = 0)")
        B, C = features.shape[:2]
        maps = self.head_2d(features.flatten(0, 1))
        return maps.reshape(B, C, *maps.shape[1:])

    def detector_maps(self, detector_px: torch.Tensor, detector_scores: torch.Tensor, map_size: int) -> torch.Tensor:
        """The detector's keypoints (B, C, K, 2) crop pixels with scores (B, C, K) -> maps (B, C, K, h, h) in the
        layout of `heatmaps_2d` (keypoint_maps.render_keypoint_maps)."""
        return render_keypoint_maps(detector_px, detector_scores, self.config.crop_px, map_size,
                                    self.config.detector_sigma_px)

    def forward(self, crops: torch.Tensor, K_crop: torch.Tensor, dist: torch.Tensor, R: torch.Tensor,
                t: torch.Tensor, center_world: torch.Tensor, view_valid: torch.Tensor | None = None,
                return_features: bool = False, grid_rotation: torch.Tensor | None = None,
                detector_px: torch.Tensor | None = None, detector_scores: torch.Tensor | None = None
                ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Score volumes of one batch of frames.

        Args:
            crops: (B, C, S, S, 3) hand crops, uint8 RGB (or float in [0, 1]).
            K_crop: (B, C, 3, 3) crop intrinsics, pixels of the crop.
            dist: (C, 5); R: (C, 3, 3); t: (C, 3) the rig, world -> camera, metres (or (B, C, ...) when
                each frame brings its own subset of the cameras).
            center_world: (B, 3) grid centres, metres, world frame.
            view_valid: (B, C) bool, views to use (default all).
            return_features: also return the 2D features (B, C, F, h, h) (for the auxiliary 2D loss).
            grid_rotation: (B, 3, 3) orientation of the grid (training augmentation); default world axes.
            detector_px: (B, C, K, 2) the detector's keypoints in crop pixels (NaN where none) and
            detector_scores: (B, C, K) their scores (0 where none); required by heatmap_source="detector".
        Returns:
            (B, K, N, N, N) score volumes, index (i, j, l) along the grid axes (world x, y, z) [, features].
        """
        cfg = self.config
        features = self.encode_views(crops)
        if cfg.heatmap_source == "detector":
            if detector_px is None or detector_scores is None:
                raise ValueError("this MVNet is detector-backed (heatmap_source='detector'): pass detector_px and "
                                 "detector_scores (the detector's keypoints in crop pixels and their scores)")
            maps = self.detector_maps(detector_px, detector_scores, features.shape[-1])
        elif cfg.heatmap_residual:
            maps = peak_normalised(self.heatmaps_2d(features))
        if cfg.heatmap_residual:
            volume, count = unproject_features(torch.cat([features, maps], dim=2), K_crop, dist, R, t, center_world,
                                               cfg.grid_size, cfg.grid_side_m, cfg.crop_px, view_valid,
                                               grid_rotation, return_count=True)
            F = features.shape[2]
            views = view_valid.sum(dim=1).clamp(min=1).to(volume.dtype) if view_valid is not None else \
                torch.full((crops.shape[0],), float(crops.shape[1]), device=volume.device)
            # Voxels seen by few views would otherwise carry one view's full heat along its ray.
            seen = (count / views[:, None, None, None])[:, None]
            unet_in = volume if cfg.heatmap_source == "detector" else volume[:, :F]
            residual = volume[:, F:] * seen  # sum over the views that see a voxel of w G, / the views
            if cfg.heatmap_source == "detector" and cfg.detector_residual == "likelihood":
                sigma_crop_px = cfg.detector_sigma_px * cfg.crop_px / cfg.feature_px
                residual = likelihood_volume(detector_px, detector_scores, K_crop, dist, R, t, center_world,
                                             cfg.grid_size, cfg.grid_side_m, cfg.crop_px, sigma_crop_px, view_valid,
                                             grid_rotation)
            elif cfg.heatmap_source == "detector" and cfg.detector_residual == "agreement":
                residual = residual * (views[:, None] / detector_weight_sum(detector_scores, view_valid))[..., None,
                                                                                                        None, None]
            scores = self.unet(unet_in, cfg.bf16) + residual
        else:
            volume = unproject_features(features, K_crop, dist, R, t, center_world, cfg.grid_size, cfg.grid_side_m,
                                        cfg.crop_px, view_valid, grid_rotation)
            scores = self.unet(volume, cfg.bf16)
        return (scores, features) if return_features else scores
