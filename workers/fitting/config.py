"""Settings of the fitting engine: loss weights (the paper's defaults), schedule and robust scales."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

# w2D of a fit from the pretrained detector's 2D keypoints where the frame has masks (the first-round w2D is 100, for
# a person's clicks). The detector's points are not clicks: they follow MediaPipe's annotation convention (fingertips
# 6-13 mm short along the bone, the thumb's base ~9 mm off) and its errors are the same in every view, so the views
# do not average them out. At w2D 100 the fit bends the hand model to that convention, the labels of D_0 inherit it,
# and what MVNet learns of the convention from them is only part of it. Measured (docs/benchmarks.md, "### Round 0's
# fits led by the silhouettes"), 32 frames of a 640 px capture, fit keypoints' median error / mean vertex error:
# w2D 100: 8.4 / 9.1 mm, 10: 5.9 / 7.4, 3: 4.1 / 6.3, 1: 3.3 / 5.2. Not lower than 3: synthetic masks are exact
# renderings of the model being fitted, which flatters the silhouettes; a real chroma key has errors the keypoints
# must still be able to outvote.
DETECTOR_KP2D_WEIGHT = 3.0


@dataclass(frozen=True)
class LossWeights:
    """Weights of L = L2D_kp + L3D_kp + L_seg + L_shape + L_pose (paper eq. 1-6) plus joint limits.

    Defaults are the paper's first-round weights ("Evaluation of Iterative Labeling"). The paper does
    not state its units; ours (docs/fitting.md) measure image distances in pixels of the capture rig's
    full sensor width (`FitConfig.reference_width_px`, 1280 px as FreiHAND's cameras), whatever the
    working resolution, and with them the paper's weights fit well:
      - kp2d: robust squared click residual (px^2), averaged over clicks;
      - kp3d: squared 3D keypoint distance in centimetres, averaged over given keypoints;
      - seg: squared silhouette distances (px^2: model outside the mask, mask not covered by the
        model; the EDT formulation of eq. 4), averaged over samples, summed over views as eq. 4;
      - shape: sum of squared betas;
      - pose: sum of squared PCA pose coefficients; nn: mean squared distance (rad^2) to the N nearest
        poses of the pose bank; limits: squared excess over anatomical joint limits (rad^2).
    """

    kp2d: float = 100.0
    kp3d: float = 0.0
    seg: float = 10.0
    shape: float = 100.0
    nn: float = 10.0
    pose: float = 0.1
    limits: float = 1000.0

    @classmethod
    def later_rounds(cls) -> LossWeights:
        """The paper's weights once MVNet's 3D keypoints exist: w2D = 50, w3D = 1000."""
        return cls(kp2d=50.0, kp3d=1000.0)

    @classmethod
    def detector_with_silhouettes(cls) -> LossWeights:
        """Round 0's fit from the pretrained detector's keypoints where the frame has masks: the first-round weights
        with w2D = DETECTOR_KP2D_WEIGHT, so the silhouettes place the joints and the keypoints mostly the start."""
        return cls(kp2d=DETECTOR_KP2D_WEIGHT)


# Where a fit's evidence comes from: a person's clicks, MVNet's prediction, or the pretrained detector (round 0).
FIT_SOURCES = ("annotation", "prediction", "detector")


def source_weights(source: str, with_masks: bool = False) -> LossWeights:
    """The loss weights of a fit by its source (FIT_SOURCES): clicks get the paper's first-round weights, MVNet's
    predictions its later-round ones, and a detector's keypoints are led by the silhouettes where the frame has masks
    (`with_masks`), else weighed like clicks (they are the only evidence). The fit jobs and `handloop bench detect`
    both take their weights from here."""
    if source not in FIT_SOURCES:
        raise ValueError(f"fit source must be one of {list(FIT_SOURCES)}, not {source!r}")
    if source == "prediction":
        return LossWeights.later_rounds()
    if source == "detector" and with_masks:
        return LossWeights.detector_with_silhouettes()
    return LossWeights()


@dataclass(frozen=True)
class FitConfig:
    """How a fit runs. Iteration counts are sized for a 2-core CPU; see docs/benchmarks.md.

    Attributes:
        weights: loss weights.
        use_silhouette: include the silhouette term when masks are given.
        robust: robust penalty on 2D click residuals ("none" = plain squares).
        reference_width_px: image distances in the loss are pixels at this image width.
        robust_scale_px: residual (reference pixels) where the robust penalty bends.
        optimizer: "levenberg_marquardt" (default: Gauss-Newton steps with adaptive damping, converges in
            tens of steps) or "adam" (the paper's optimiser; needs about 40 + 160 steps, see `adam`).
        global_iterations: most steps of the first stage (global rotation, translation and pose from
            keypoints, shape frozen); Levenberg-Marquardt stops a frame earlier once it converges.
        full_iterations: most steps of the second stage (every parameter, silhouettes included).
        learning_rate: Adam step size (Adam only).
        start_candidates: Levenberg-Marquardt starts per frame (the best-placed candidate articulations of
            the initialisation) taken through the first stage; the fit landscape has local minima.
        finalists: of those, how many (lowest full objective) go through the second stage; the one with
            the lowest objective is the fit. Adam uses one start.
        lm_damping: initial Levenberg-Marquardt damping, relative to the Hessian's diagonal.
        lm_tolerance: a frame stops once an accepted step lowers its objective by less than this fraction.
        num_pca_comps: PCA components used for the articulation (paper: pose as PCA coefficients).
        nn_neighbours: N of the nearest-neighbour pose prior.
        silhouette_vertices: vertices sampled (farthest-point) for the silhouette term.
        boundary_points: mask boundary points sampled per view for the coverage term.
        silhouette_cap_px: scale (reference pixels) of the robust penalty of the "model outside the mask"
            term, for foreground masks (`masks_include_forearm`: chroma key), which hold everything in front
            of the background, so the model lies inside them: only mask errors need the cap.
        coverage_cap_px: the same for the "mask not covered" term with foreground masks, small: they also
            hold objects, sleeves and the forearm stump, which the model must not reach for.
        hand_mask_silhouette_cap_px: "model outside the mask" with hand-only masks (HandSegNet, the visible
            hand), small: they lack what an object or the forearm hides, which the model must not be
            pushed out from behind.
        hand_mask_coverage_cap_px: "mask not covered" with hand-only masks.
        coverage_tangent_weight: weight of the offset along the mask boundary, relative to the offset
            along its normal, in the "mask not covered" term (1: Euclidean distance). See docs/fitting.md.
        cut_forearm: cut masks at the wrist before comparing them with the model.
        seed: seeds everything random in a fit (sampling of boundary points).
        torch_threads: intra-op threads during a fit (None: leave torch's setting). A fit is many
            small operations: one thread avoids OpenMP barrier stalls, which made fits 10x slower on
            a loaded 2-core machine (measured); parallelism comes from batching and worker processes.
    """

    weights: LossWeights = LossWeights()
    use_silhouette: bool = True
    robust: Literal["none", "geman_mcclure", "huber"] = "geman_mcclure"
    reference_width_px: float = 1280.0
    robust_scale_px: float = 32.0
    optimizer: Literal["levenberg_marquardt", "adam"] = "levenberg_marquardt"
    global_iterations: int = 12
    full_iterations: int = 30
    learning_rate: float = 0.03
    start_candidates: int = 8
    finalists: int = 1
    lm_damping: float = 1e-2
    lm_tolerance: float = 1e-4
    num_pca_comps: int = 45
    nn_neighbours: int = 5
    silhouette_vertices: int = 384
    boundary_points: int = 96
    silhouette_cap_px: float = 100.0
    coverage_cap_px: float = 10.0
    hand_mask_silhouette_cap_px: float = 25.0
    hand_mask_coverage_cap_px: float = 20.0
    coverage_tangent_weight: float = 0.5
    cut_forearm: bool = True
    seed: int = 0
    torch_threads: int | None = 1

    def __post_init__(self) -> None:
        counts = {"global_iterations": 0, "full_iterations": 0, "start_candidates": 1, "finalists": 1,
                  "num_pca_comps": 1, "nn_neighbours": 1, "silhouette_vertices": 1, "boundary_points": 1}
        for name, least in counts.items():
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < least:
                raise ValueError(f"FitConfig.{name} must be an integer >= {least}, got {value!r}")
        if self.num_pca_comps > 45:
            raise ValueError(f"FitConfig.num_pca_comps must be at most 45, got {self.num_pca_comps}")
        positive = ("reference_width_px", "robust_scale_px", "learning_rate", "lm_damping", "lm_tolerance",
                    "silhouette_cap_px", "coverage_cap_px", "hand_mask_silhouette_cap_px",
                    "hand_mask_coverage_cap_px")
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"FitConfig.{name} must be a positive finite number, got {value!r}")
        if not (math.isfinite(self.coverage_tangent_weight) and self.coverage_tangent_weight >= 0):
            raise ValueError(f"FitConfig.coverage_tangent_weight must be >= 0, got {self.coverage_tangent_weight!r}")
        for name, value in vars(self.weights).items():
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"LossWeights.{name} must be a finite number >= 0, got {value!r}")
        if self.optimizer not in ("levenberg_marquardt", "adam"):
            raise ValueError(f"FitConfig.optimizer must be 'levenberg_marquardt' or 'adam', got {self.optimizer!r}")
        if self.robust not in ("none", "geman_mcclure", "huber"):
            raise ValueError(f"FitConfig.robust must be 'none', 'geman_mcclure' or 'huber', got {self.robust!r}")

    @classmethod
    def adam(cls, **changes) -> FitConfig:
        """The Adam schedule (the paper's optimiser): 40 + 160 steps, cosine-decayed learning rate."""
        return cls(**{"optimizer": "adam", "global_iterations": 40, "full_iterations": 160, **changes})

    def with_weights(self, **changes: float) -> FitConfig:
        return replace(self, weights=replace(self.weights, **changes))
