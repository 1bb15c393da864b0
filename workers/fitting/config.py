"""Settings of the fitting engine: loss weights (the paper's defaults), schedule and robust scales."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal


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


@dataclass(frozen=True)
class FitConfig:
    """How a fit runs. Iteration counts are sized for a 2-core CPU; see docs/benchmarks.md.

    Attributes:
        weights: loss weights.
        use_silhouette: include the silhouette term when masks are given.
        robust: robust penalty on 2D click residuals ("none" = plain squares).
        reference_width_px: image distances in the loss are pixels at this image width.
        robust_scale_px: residual (reference pixels) where the robust penalty bends.
        global_iterations: first stage, only global rotation + translation + coarse pose.
        full_iterations: second stage, every parameter, silhouettes included.
        learning_rate: Adam step size.
        num_pca_comps: PCA components used for the articulation (paper: pose as PCA coefficients).
        nn_neighbours: N of the nearest-neighbour pose prior.
        silhouette_vertices: vertices sampled (farthest-point) for the silhouette term.
        boundary_points: mask boundary points sampled per view for the coverage term.
        silhouette_cap_px: distances (reference pixels) above which the "model outside the mask" term
            stops pulling (mask errors).
        coverage_cap_px: the same for the "mask not covered" term, smaller: chroma-key masks also
            hold objects, sleeves and the forearm stump, which the model must not reach for.
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
    global_iterations: int = 40
    full_iterations: int = 160
    learning_rate: float = 0.03
    num_pca_comps: int = 45
    nn_neighbours: int = 5
    silhouette_vertices: int = 384
    boundary_points: int = 96
    silhouette_cap_px: float = 100.0
    coverage_cap_px: float = 20.0
    cut_forearm: bool = True
    seed: int = 0
    torch_threads: int | None = 1

    def with_weights(self, **changes: float) -> FitConfig:
        return replace(self, weights=replace(self.weights, **changes))
