"""What a fit returns: parameters, geometry, model masks and the diagnostics reviewers and the
verification heuristic read."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, eq=False)
class FitDiagnostics:
    """Attributes:
        iou_per_view: (C,) IoU of the model mask with the (wrist-cut) given mask; NaN without a mask.
        residual_2d_px: (C, 21) distance of each projected model keypoint to its click, pixels; NaN
            where not clicked.
        residual_3d_mm: (21,) distance to the given 3D keypoints, millimetres; NaN where none.
        loss_terms: final value of each weighted loss term (name -> value).
        iterations: optimisation steps taken.
        seconds: wall time of the fit, this frame's share of its batch.
    """

    iou_per_view: np.ndarray
    residual_2d_px: np.ndarray
    residual_3d_mm: np.ndarray
    loss_terms: dict[str, float]
    iterations: int
    seconds: float

    def to_dict(self) -> dict:
        def clean(a: np.ndarray) -> list:
            return [None if not np.isfinite(x) else round(float(x), 4) for x in np.ravel(a)]

        return {
            "iou_per_view": clean(self.iou_per_view),
            "mean_iou": _nanmean(self.iou_per_view),
            "residual_2d_px": np.where(np.isfinite(self.residual_2d_px), self.residual_2d_px, np.nan).round(3).tolist(),
            "mean_residual_2d_px": _nanmean(self.residual_2d_px),
            "residual_3d_mm": clean(self.residual_3d_mm),
            "loss_terms": {k: round(v, 6) for k, v in self.loss_terms.items()},
            "iterations": self.iterations,
            "seconds": round(self.seconds, 4),
        }


def _nanmean(values: np.ndarray) -> float | None:
    finite = np.asarray(values)[np.isfinite(values)]
    return round(float(finite.mean()), 4) if finite.size else None


@dataclass(frozen=True, eq=False)
class FitResult:
    """One fitted frame. Parameters follow docs/conventions.md (flat-hand articulation).

    Attributes:
        betas: (10,) shape.  pose: (45,) articulation, axis-angle radians.
        global_orient: (3,) axis-angle about the wrist joint.  transl: (3,) metres.
        vertices: (V, 3) metres, world.  keypoints: (21, 3) metres, world, FreiHAND order.
        model_masks: per view (H_c, W_c) bool silhouette of the fitted model.
        diagnostics: see FitDiagnostics.
        hand_model: name of the hand model that made this fit.
    """

    betas: np.ndarray
    pose: np.ndarray
    global_orient: np.ndarray
    transl: np.ndarray
    vertices: np.ndarray
    keypoints: np.ndarray
    model_masks: tuple[np.ndarray, ...]
    diagnostics: FitDiagnostics
    hand_model: str
    extras: dict = field(default_factory=dict)

    @property
    def theta(self) -> np.ndarray:
        """(61,) the paper's parameter vector: shape 10, articulation 45, global rotation 3, translation 3."""
        return np.concatenate([self.betas, self.pose, self.global_orient, self.transl])
