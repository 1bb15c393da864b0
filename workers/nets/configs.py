"""Network configurations: frozen dataclasses with sizes and units (docs/networks.md).

`cpu-small` trains to usefulness in minutes on a laptop CPU; `paper` reproduces the sizes of the FreiHAND
supplementary ("MVNet", implementation details): 224 px crops, 28 x 28 x 128 features after 12
convolutions, a 64^3 grid of side 0.4 m, Adam, 8 views (one frame) per step. `tiny` exists for tests.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal

LossKind = Literal["scorevolume", "softargmax"]
HeatmapSource = Literal["learned", "detector"]
DetectorResidual = Literal["views", "agreement", "likelihood"]


@dataclass(frozen=True)
class MVNetConfig:
    """MVNet sizes and training settings.

    Attributes:
        crop_px: side of the square hand crop fed to the 2D CNN, pixels.
        crop_radius_m: half side of the square the crop covers at the hand centre's depth, metres (the
            crop's pixel size follows from each camera's focal length and depth).
        backbone_widths: channels of the 2D CNN, one stage per entry; a 2x max-pool between stages.
        convs_per_stage: 3x3 convolutions per 2D stage.
        stem_stride: stride of the first 2D convolution (2 halves the cost of a larger crop).
        norm: "group" or "batch" normalisation in both CNNs (batch: faster on CPU, and learned faster here).
        bf16: run the convolutions in bfloat16 where the device does so natively (autocast; weights, losses and
            unprojection stay float32; float32 on CPUs without AVX512-BF16 / AMX, see mvnet.native_bf16).
        decoder_levels: upsampling steps (with skip connections) after the deepest 2D stage; the feature map
            has side crop_px / 2^(len(backbone_widths) - 1 - decoder_levels).
        feature_channels: channels of the 2D feature map f_i (last 1x1 convolution).
        grid_size: voxels per side N of the cubic grid.
        grid_side_m: side of the cubic grid centred on the hand, metres (paper: 0.4).
        unet_widths: channels of the 3D U-Net per level (level 0 = full grid resolution).
        sigma_voxels: standard deviation of the Gaussian score targets, voxels (paper: 2).
        loss: "scorevolume" (paper eq. 7, L2 to peak-normalised Gaussians) or "softargmax".
        aux_2d_weight: weight of an auxiliary 2D keypoint loss on the shared features (deep supervision of
            the 2D CNN with the keypoints projected into each crop); 0 = off (the paper's loss alone).
        aux_2d_sigma_px: standard deviation of the 2D targets, pixels of the feature map.
        batch_frames: frames per training step (each frame brings all its views to the 2D CNN).
        lr: Adam learning rate.
        weight_decay: Adam weight decay.
        center_jitter_m: standard deviation of the random grid-centre shift in training, metres.
        cut_paste_prob: probability of replacing a green-screen view's background in training.
        recolor: strength of the random skin-tone change of pasted foregrounds (0 = none, 1 = full range).
        color_jitter: amplitude of the random per-view gain and offset in training.
        crop_rotation_deg: maximal random in-plane rotation of a training crop (its intrinsics follow).
        crop_scale: maximal random log-scale of a training crop (0.1 = +-10 %).
        train_views: views per frame in a training step (a random subset; 0 = all). The view average makes
            MVNet indifferent to the count; fewer views per step = more frames per CPU second.
        warmup_2d_fraction: fraction of the training budget spent on the auxiliary 2D loss alone (no 3D
            network: about twice the steps per second) before the whole network trains.
        grid_rotation: randomly orient the voxel grid in training (labels rotate along).
        heatmap_residual: add the view-averaged 2D keypoint maps (the auxiliary head's, peak-normalised,
            weighted by the fraction of views that see a voxel) to the 3D U-Net's output, so the score
            volumes start from a triangulation-like estimate the U-Net refines (needs aux_2d_weight > 0).
        heatmap_source: "learned" (the auxiliary 2D head's maps) or "detector" (the pretrained detector's
            keypoints rendered as Gaussians of `detector_sigma_px` feature-map pixels, keypoint_maps.py).
        detector_sigma_px: standard deviation of the detector's rendered maps, pixels of the feature map.
        detector_residual: detector-backed only, the heat-map residual's normalisation: "views" = the views'
            score-weighted maps summed over the views that see a voxel, divided by the number of views (its peak is
            about the detectors' mean score); "agreement" = divided by the sum of the weights instead, a weighted
            average of the views' Gaussians: 1 where every view that found the keypoint agrees, as the peak-normalised
            score targets (so the U-Net learns a shift, not a rescaling, and eq. 8 reads the views' agreement);
            "likelihood" = at each voxel the Gaussian of the weighted mean squared reprojection distance to the views'
            keypoints (keypoint_maps.likelihood_volume): the same peak without the rays the averages leave along each
            view's line of sight (which the L2 loss first spends its steps removing).
        unet_image_features: detector-backed only: the 3D U-Net sees the 2D CNN's unprojected image features
            beside the detector's maps; False: the detector's maps alone (no 2D CNN at all): the refinement is
            learned from the views' geometry, which carries over to unseen hands from a few dozen labels where
            image features learned from them do not (docs/networks.md, "Detector-backed MVNet").
        detector_offsets: detector-backed only: before the detections become maps, move them by per-keypoint
            offsets learned from the training labels (workers.detector.keypoint_offsets: the detector's keypoint
            convention against the hand model's); the offsets are part of the weights (a buffer), so prediction
            applies what training learned.
        detector_pose_correction: with detector_offsets, also a correction that depends on the lifted hand's pose
            (keypoint_offsets.PoseCorrection, ridge regression in the palm's frame), learned where the round has
            enough labelled frames (POSE_MIN_FRAMES) and saved with the weights like the offsets.
        detector_window_m: detector-backed only, prediction only (not part of the weights): the readout looks for
            each keypoint's peak within this distance (metres) of its lifted, offset-corrected detector keypoint
            (predict.window_scores), so the network refines the lift and a volume peaking elsewhere reads as unsure;
            0: the whole grid (the paper).
    """

    crop_px: int = 32
    crop_radius_m: float = 0.15
    backbone_widths: tuple[int, ...] = (16, 32)
    convs_per_stage: int = 2
    decoder_levels: int = 0
    stem_stride: int = 1
    norm: str = "group"
    bf16: bool = False
    feature_channels: int = 16
    grid_size: int = 16
    grid_side_m: float = 0.4
    unet_widths: tuple[int, ...] = (16, 32, 48)
    sigma_voxels: float = 2.0
    loss: LossKind = "scorevolume"
    aux_2d_weight: float = 0.0
    aux_2d_sigma_px: float = 1.0
    batch_frames: int = 4
    lr: float = 1e-3
    weight_decay: float = 0.0
    center_jitter_m: float = 0.015
    cut_paste_prob: float = 0.5
    recolor: float = 0.0
    color_jitter: float = 0.15
    crop_rotation_deg: float = 0.0
    crop_scale: float = 0.0
    train_views: int = 0
    warmup_2d_fraction: float = 0.0
    grid_rotation: bool = False
    heatmap_residual: bool = False
    heatmap_source: HeatmapSource = "learned"
    detector_sigma_px: float = 1.0
    detector_residual: DetectorResidual = "views"
    unet_image_features: bool = True
    detector_offsets: bool = False
    detector_pose_correction: bool = False
    detector_window_m: float = 0.0

    def __post_init__(self) -> None:
        if self.loss not in ("scorevolume", "softargmax"):
            raise ValueError(f"loss must be 'scorevolume' or 'softargmax', got {self.loss!r}")
        if not 0 <= self.decoder_levels < len(self.backbone_widths):
            raise ValueError(f"decoder_levels must be in 0..{len(self.backbone_widths) - 1}")
        stride = self.stem_stride * 2 ** (len(self.backbone_widths) - 1)
        if self.crop_px % stride:
            raise ValueError(f"crop_px={self.crop_px} must be divisible by the backbone stride {stride}")
        if self.grid_size % 2 ** (len(self.unet_widths) - 1):
            raise ValueError(f"grid_size={self.grid_size} must be divisible by 2^(levels-1) of the U-Net")
        if self.heatmap_source not in ("learned", "detector"):
            raise ValueError(f"heatmap_source must be 'learned' or 'detector', got {self.heatmap_source!r}")
        if self.heatmap_source == "detector" and not self.heatmap_residual:
            raise ValueError("heatmap_source='detector' needs heatmap_residual=True (the detector's maps enter "
                             "through the unprojection and the heat-map residual)")
        if not isinstance(self.detector_offsets, bool):
            raise ValueError(f"detector_offsets must be true or false, got {self.detector_offsets!r}")
        if self.detector_offsets and self.heatmap_source != "detector":
            raise ValueError("detector_offsets needs heatmap_source='detector' (they correct the detector's keypoints)")
        if not isinstance(self.detector_pose_correction, bool):
            raise ValueError(f"detector_pose_correction must be true or false, got {self.detector_pose_correction!r}")
        if self.detector_pose_correction and not self.detector_offsets:
            raise ValueError("detector_pose_correction needs detector_offsets=True (it corrects what they leave)")
        window = self.detector_window_m
        if isinstance(window, bool) or not isinstance(window, (int, float)) or not math.isfinite(window) or window < 0:
            raise ValueError(f"detector_window_m must be a finite distance >= 0 in metres, got {window!r}")
        if window > 0 and self.heatmap_source != "detector":
            raise ValueError("detector_window_m needs heatmap_source='detector' (the window is around the detector's "
                             "lifted keypoints)")
        if self.heatmap_source == "detector" and not self.detector_sigma_px > 0:
            raise ValueError(f"detector_sigma_px must be positive, got {self.detector_sigma_px}")
        if self.detector_residual not in ("views", "agreement", "likelihood"):
            raise ValueError(f"detector_residual must be 'views', 'agreement' or 'likelihood', got "
                             f"{self.detector_residual!r}")
        if not self.unet_image_features and (self.heatmap_source != "detector" or self.aux_2d_weight > 0):
            raise ValueError("unet_image_features=False needs heatmap_source='detector' and aux_2d_weight=0 (without "
                             "image features there is no 2D CNN for a 2D head)")
        learned_maps = self.heatmap_residual and self.heatmap_source == "learned"
        if (learned_maps or self.warmup_2d_fraction > 0) and self.aux_2d_weight <= 0:
            raise ValueError("heatmap_residual (learned maps) and warmup_2d_fraction need the 2D keypoint head "
                             "(aux_2d_weight > 0)")
        if not (self.grid_side_m > 0 and self.crop_radius_m > 0 and self.sigma_voxels > 0):
            raise ValueError("grid_side_m, crop_radius_m and sigma_voxels must be positive")

    @property
    def feature_px(self) -> int:
        """Side of the 2D feature map, pixels of the feature grid."""
        return self.crop_px // (self.stem_stride * 2 ** (len(self.backbone_widths) - 1 - self.decoder_levels))

    @property
    def voxel_m(self) -> float:
        """Edge length of one voxel, metres."""
        return self.grid_side_m / self.grid_size


@dataclass(frozen=True)
class HandSegNetConfig:
    """HandSegNet (hand3d, Zimmermann & Brox 2017) sizes and training settings.

    A fully convolutional encoder-decoder run on square views of the hand at two scales: a coarse pass
    over the whole image (resampled so that `crop_px` pixels span 2 `coarse_radius_m` at the rig's
    centre) localises the hand; a fine pass on the crop of half side `crop_radius_m` around the
    triangulated centre gives the mask, warped back into the image. Training crops take radii between
    the two, so one network serves both passes.

    Attributes:
        widths: channels per level (a 2x max-pool between levels).
        stem_stride: stride of the first convolution; 2 runs the U-Net at half resolution and adds a light
            full-resolution head that sees the image (cheap, edge-accurate masks).
        norm: "group" or "batch" normalisation.
        bf16: run the convolutions in bfloat16 where native (autocast; see mvnet.native_bf16).
        crop_px: side of the network's square input, pixels.
        crop_radius_m: half side of the fine crop at the hand's depth, metres.
        coarse_radius_m: half side that `crop_px` pixels cover in the coarse pass, metres.
        batch_size: crops per training step.
        lr: Adam learning rate.
        fine_prob: probability that a training crop is at the fine scale (else log-uniform up to coarse).
        center_jitter: standard deviation of the training crop's centre shift, as a fraction of its radius
            (the fine pass must cope with the error of the coarser passes before it).
        cut_paste_prob: probability of replacing a green-screen image's background in training.
        recolor: strength of the random skin-tone change of pasted foregrounds (0 = none, 1 = full range).
        color_jitter: amplitude of the random gain and offset in training.
        threshold: probability above which a pixel is hand.
        round_min_steps: steps a bootstrap round's training makes at least, past its seconds budget if need be
            (None: the budget alone). cpu-small: 1650. A 2-core CPU without native bfloat16 (AVX2, float32)
            makes ~830 in the default 90 s, one with it ~1300; the cluttered frames, whose IoU reference is
            HandSegNet's mask, passed the heuristic 10 / 11 / 26 times by round 2 with 830 / 1300 / 1650 steps
            (step-counted sims, docs/benchmarks.md "### HandSegNet's steps with MVNet's held").
    """

    widths: tuple[int, ...] = (12, 24, 32)
    stem_stride: int = 1
    norm: str = "group"
    bf16: bool = False
    crop_px: int = 80
    crop_radius_m: float = 0.15
    coarse_radius_m: float = 0.45
    batch_size: int = 8
    lr: float = 2e-3
    fine_prob: float = 0.6
    center_jitter: float = 0.1
    cut_paste_prob: float = 0.7
    recolor: float = 0.0
    color_jitter: float = 0.2
    threshold: float = 0.5
    round_min_steps: int | None = None

    def __post_init__(self) -> None:
        if self.round_min_steps is not None and (isinstance(self.round_min_steps, bool)
                                                 or not isinstance(self.round_min_steps, int)
                                                 or self.round_min_steps < 1):
            raise ValueError(f"round_min_steps must be a positive integer or None, got {self.round_min_steps!r}")
        if self.crop_px % (self.stem_stride * 2 ** (len(self.widths) - 1)):
            raise ValueError(f"crop_px={self.crop_px} must be divisible by stem_stride * 2^(levels-1)")
        if not 0 < self.crop_radius_m <= self.coarse_radius_m:
            raise ValueError("need 0 < crop_radius_m <= coarse_radius_m")


@dataclass(frozen=True)
class NetsConfig:
    """A named pair of network configurations."""

    name: str
    mvnet: MVNetConfig = field(default_factory=MVNetConfig)
    handsegnet: HandSegNetConfig = field(default_factory=HandSegNetConfig)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> NetsConfig:
        mv = {k: tuple(v) if isinstance(v, list) else v for k, v in data["mvnet"].items()}
        hs = {k: tuple(v) if isinstance(v, list) else v for k, v in data["handsegnet"].items()}
        return cls(name=data["name"], mvnet=MVNetConfig(**mv), handsegnet=HandSegNetConfig(**hs))


# The readout window's radius: 2-3 voxels of the detector-backed grid; the network's refinements of the lift are
# ~6 mm at a frame's largest (median), and 20, 30, 40 and 60 mm gave 14.3, 14.3, 14.5 and 14.6 mm mean error.
DETECTOR_WINDOW_M = 0.03


def detector_backed_variant(config: NetsConfig, grid_size: int = 24, grid_side_m: float = 0.28) -> NetsConfig:
    """`config` with the detector's keypoint maps in place of MVNet's learned 2D head (`<name>-detector`).

    Sized for the detector's precision (docs/networks.md, "Detector-backed MVNet"): a grid of `grid_side_m` (the
    crop's side: a hand spans ~0.2 m, the grid is centred on its lifted keypoints) at `grid_size` voxels (0.28 m /
    24 = 11.7 mm; 32 voxels were as precise per step and 2.3x slower per step on this CPU), Gaussian targets of the
    detector maps' width (1.5 voxels = 17.5 mm = 1 pixel of the 16 x 16 map over 0.28 m), the likelihood residual
    (peak 1 where the views agree, as the targets; its maps sqrt(2/3) as wide, so that it has the targets' width;
    the agreement residual before 2026-12-03 09:10), the 3D U-Net on the detector's maps alone: no 2D CNN, no
    2D head, no 2D-only warm-up; and the detector's keypoint offsets learned from the labels (since 2026-12-03
    18:40: held-out error 6.16 -> 4.13 mm median after 600 steps, docs/benchmarks.md "Detector keypoint
    offsets") and, since 2026-12-05, a pose-dependent correction after them (held-out largest keypoint error of a
    frame 28 -> 17.5 mm, docs/benchmarks.md "A pose-dependent correction"); and the readout within 3 cm of each lifted
    keypoint (since 2026-12-03 22:10: the round-1 network of the sim on 80 green-screen frames, mean error 17.3 ->
    14.3 mm, median unchanged, docs/benchmarks.md "MVNet's readout window"))."""
    sigma_map_px = 1.0
    # the maps' width in metres at the hand (one map pixel spans 2 crop_radius_m / feature_px) in voxels
    sigma_voxels = sigma_map_px * (2 * config.mvnet.crop_radius_m / config.mvnet.feature_px) / (grid_side_m / grid_size)
    # The likelihood residual of Gaussians of width s is ~s sqrt(3/2) wide about the triangulated point (views
    # spread around it): s = sqrt(2/3) of the targets' width makes it the targets' shape where the views agree,
    # so training need not narrow it (which lowered the peaks, eq. 8: docs/benchmarks.md, "MVNet confidence").
    mvnet = replace(config.mvnet, warmup_2d_fraction=0.0, heatmap_source="detector",
                    detector_sigma_px=round(sigma_map_px * math.sqrt(2 / 3), 4),
                    grid_size=grid_size, grid_side_m=grid_side_m, sigma_voxels=round(sigma_voxels, 3),
                    detector_residual="likelihood", unet_image_features=False, aux_2d_weight=0.0,
                    detector_offsets=True, detector_pose_correction=True, detector_window_m=DETECTOR_WINDOW_M)
    return replace(config, name=f"{config.name}-detector", mvnet=mvnet)


def coarse_detector_variant(config: NetsConfig) -> NetsConfig:
    """The first detector-backed design (2026-12-02, kept to measure beside the current one): `config`'s grid (16^3
    over 0.4 m, targets of 2 voxels = 50 mm), the detector's maps beside the 2D CNN's image features into the U-Net,
    the residual divided by the number of views (`<name>-detector-coarse`)."""
    mvnet = replace(config.mvnet, warmup_2d_fraction=0.0, heatmap_source="detector", detector_sigma_px=1.0)
    return replace(config, name=f"{config.name}-detector-coarse", mvnet=mvnet)


def config_digest(config: MVNetConfig | HandSegNetConfig) -> str:
    """A short hash of the fields that define what the weights mean: architecture, loss and metric scales
    (checkpoints refuse a configuration with another digest)."""
    data = asdict(config)
    arch_keys = {
        "crop_px", "backbone_widths", "convs_per_stage", "stem_stride", "norm", "decoder_levels", "feature_channels",
        "grid_size", "unet_widths", "widths", "loss", "crop_radius_m", "grid_side_m", "coarse_radius_m",
    }
    arch = {k: v for k, v in sorted(data.items()) if k in arch_keys}
    if data.get("aux_2d_weight", 0) > 0:  # the 2D head exists only then (its weight's value does not matter)
        arch["head_2d"] = True
    if data.get("heatmap_residual"):
        arch["heatmap_residual"] = True
    if data.get("heatmap_source", "learned") != "learned":  # absent from paper-only digests: those stay as they were
        arch["heatmap_source"] = data["heatmap_source"]
        arch["detector_sigma_px"] = data["detector_sigma_px"]
    if data.get("detector_residual", "views") != "views":  # absent where "views": earlier digests stay as they were
        arch["detector_residual"] = data["detector_residual"]
    if not data.get("unet_image_features", True):  # absent where True: earlier digests stay as they were
        arch["unet_image_features"] = False
    if data.get("detector_offsets"):  # absent where False: earlier digests stay as they were
        arch["detector_offsets"] = True
    if data.get("detector_pose_correction"):  # absent where False: earlier digests stay as they were
        arch["detector_pose_correction"] = True
    return hashlib.sha1(json.dumps(arch, sort_keys=True).encode()).hexdigest()[:12]


CONFIGS: dict[str, NetsConfig] = {
    "cpu-small": NetsConfig(
        name="cpu-small",
        mvnet=MVNetConfig(crop_px=64, crop_radius_m=0.14, backbone_widths=(32, 64, 128), stem_stride=2,
                          decoder_levels=1, norm="batch", bf16=True, feature_channels=32, unet_widths=(16, 32, 48),
                          aux_2d_weight=1.0, heatmap_residual=True, warmup_2d_fraction=0.5, lr=3e-3,
                          center_jitter_m=0.02, cut_paste_prob=0.9, recolor=1.0, crop_rotation_deg=30.0,
                          crop_scale=0.1, train_views=6),
        handsegnet=HandSegNetConfig(widths=(16, 32, 64), stem_stride=2, norm="batch", bf16=True, crop_px=104,
                                    crop_radius_m=0.14, batch_size=8, lr=2e-3, fine_prob=0.6, center_jitter=0.25,
                                    cut_paste_prob=0.9, recolor=1.0, round_min_steps=1650),
    ),
    "paper": NetsConfig(
        name="paper",
        mvnet=MVNetConfig(crop_px=224, crop_radius_m=0.15, backbone_widths=(64, 128, 256, 128), convs_per_stage=3,
                          feature_channels=128, grid_size=64, unet_widths=(32, 64, 128, 256), batch_frames=1,
                          lr=1e-4, center_jitter_m=0.02),
        handsegnet=HandSegNetConfig(widths=(64, 128, 256, 512), crop_px=256, batch_size=8, lr=1e-4),
    ),
    "tiny": NetsConfig(
        name="tiny",
        mvnet=MVNetConfig(crop_px=32, backbone_widths=(8, 8), convs_per_stage=1, feature_channels=8, grid_size=16,
                          unet_widths=(8, 16), batch_frames=2, lr=3e-3, center_jitter_m=0.0, cut_paste_prob=0.0,
                          color_jitter=0.0),
        handsegnet=HandSegNetConfig(widths=(8, 16), crop_px=32, batch_size=4, lr=5e-3),
    ),
}
CONFIGS["cpu-small-detector"] = detector_backed_variant(CONFIGS["cpu-small"])
CONFIGS["cpu-small-detector-coarse"] = coarse_detector_variant(CONFIGS["cpu-small"])


# The paper-only configuration each detector-backed one falls back to when the detector is not installed.
PAPER_ONLY: dict[str, str] = {"cpu-small-detector": "cpu-small", "cpu-small-detector-coarse": "cpu-small"}


def paper_only(config: NetsConfig) -> NetsConfig:
    """The paper-only counterpart of `config` (itself when it does not use the detector): the named one of
    PAPER_ONLY, else the same sizes with the learned 2D head's maps."""
    if config.mvnet.heatmap_source == "learned":
        return config
    if config.name in PAPER_ONLY:
        return CONFIGS[PAPER_ONLY[config.name]]
    mv = config.mvnet
    return replace(config, name=f"{config.name}-paper-only",
                   mvnet=replace(mv, heatmap_source="learned", aux_2d_weight=mv.aux_2d_weight or 1.0,
                                 detector_residual="views", unet_image_features=True,
                                 detector_offsets=False, detector_pose_correction=False, detector_window_m=0.0))


def get_config(name: str, **mvnet_overrides: Any) -> NetsConfig:
    """The named configuration ("cpu-small", "cpu-small-detector", "cpu-small-detector-coarse", "paper", "tiny"),
    optionally with MVNet fields replaced."""
    if name not in CONFIGS:
        raise ValueError(f"unknown network configuration {name!r}; choose from {sorted(CONFIGS)}")
    config = CONFIGS[name]
    if mvnet_overrides:
        config = replace(config, mvnet=replace(config.mvnet, **mvnet_overrides))
    return config
