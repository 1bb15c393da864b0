"""What a fit returns: parameters, geometry, model masks and the diagnostics reviewers and the
verification heuristic read."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workers.handmodel.params import HandParams


@dataclass(frozen=True, eq=False)
class FitDiagnostics:
    """Attributes:
        iou_per_view: (C,) IoU of the model mask with the (wrist-cut) given mask; NaN without a mask.
        residual_2d_px: (C, 21) distance of each projected model keypoint to its click, pixels; NaN
            where not clicked.
        accepted_2d: (C, 21) bool, True where that click is a proposal the annotator accepted (not placed by
            hand). A fit lands near the proposals it was given, so their residuals say little about it: the
            summaries keep them apart and `mean_residual_2d_px` is over the points placed by hand when any.
        points_source: "annotation" (residual_2d_px is to annotators' points: placed by hand or accepted) or
            "detector" (to the pretrained detector's keypoints: none placed by hand).
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
    accepted_2d: np.ndarray | None = None
    points_source: str = "annotation"

    def by_origin(self) -> dict[str, dict[str, float | int | None]]:
        """The 2D residuals to points placed by hand ("clicked") apart from accepted proposals ("accepted") and
        the detector's keypoints ("detector"): each count, mean and max in pixels (None without any)."""
        finite = np.isfinite(self.residual_2d_px)
        accepted = np.zeros_like(finite) if self.accepted_2d is None else np.asarray(self.accepted_2d, dtype=bool)
        detector = finite if self.points_source == "detector" else np.zeros_like(finite)
        out: dict[str, dict[str, float | int | None]] = {}
        for name, chosen in (("clicked", finite & ~accepted & ~detector), ("accepted", finite & accepted & ~detector),
                             ("detector", detector)):
            values = self.residual_2d_px[chosen]
            out[name] = {"n": int(values.size), "mean_px": round(float(values.mean()), 4) if values.size else None,
                         "max_px": round(float(values.max()), 4) if values.size else None}
        return out

    def to_dict(self) -> dict:
        def clean(a: np.ndarray) -> list:
            return [None if not np.isfinite(x) else round(float(x), 4) for x in np.ravel(a)]

        origin = self.by_origin()
        accepted = np.zeros(np.shape(self.residual_2d_px), bool) if self.accepted_2d is None else self.accepted_2d
        # Over the points placed by hand when there are any (proposals would flatter the fit), else over what
        # the fit had (accepted proposals, the detector's keypoints); `mean_residual_2d_of` names which.
        of = next((name for name in ("clicked", "accepted", "detector") if origin[name]["n"]), None)
        return {
            "iou_per_view": clean(self.iou_per_view),
            "mean_iou": _nanmean(self.iou_per_view),
            "residual_2d_px": np.where(np.isfinite(self.residual_2d_px), self.residual_2d_px, np.nan).round(3).tolist(),
            "mean_residual_2d_px": origin[of]["mean_px"] if of else None,
            "mean_residual_2d_of": of,
            "residual_2d_by_origin": origin,
            "accepted_2d": [[int(c), int(k)] for c, k in np.argwhere(accepted & np.isfinite(self.residual_2d_px))],
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
    def params(self) -> HandParams:
        """The fitted parameters as one value (betas, pose, global_orient, transl)."""
        return HandParams(self.betas, self.pose, self.global_orient, self.transl)

    @property
    def theta(self) -> np.ndarray:
        """(61,) the paper's parameter vector: shape 10, articulation 45, global rotation 3, translation 3."""
        return self.params.to_theta()
