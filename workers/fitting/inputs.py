"""What a fit is given for one frame, and the checks that refuse garbage before any optimisation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.geometry.camera import Camera
from workers.handmodel.keypoints import NUM_KEYPOINTS

# Weight of a click marked "occluded (best guess)" relative to a visible one.
OCCLUDED_CLICK_WEIGHT = 0.3
# Factor on the weight of a point the annotator accepted from a proposal (triangulation of their own clicks,
# the fit, MVNet, the detector) instead of placing it: inverse variance, (sigma_click / sigma_accepted)^2 with
# sigma_click ~ 2 px (the simulated annotators' click noise) and sigma_accepted ~ 4 px (an accepted proposal
# is one a person let through at a glance; the bench's scripted annotator corrects those more than 4 px off).
# A triangulated proposal is moreover the annotator's own clicks again, not new evidence.
PROPOSAL_CLICK_WEIGHT = 0.25
# Where a frame's 2D points come from (FrameObservations.points_source).
POINTS_SOURCES = ("annotation", "detector")


class FitInputError(ValueError):
    """The observations cannot support a fit; the message says which input is at fault."""


@dataclass(frozen=True, eq=False)
class FrameObservations:
    """Observations of one multi-view frame.

    Attributes:
        clicks_px: (C, 21, 2) clicked pixel positions per view and FreiHAND keypoint; NaN = none.
        click_weights: (C, 21) >= 0: 1 visible, OCCLUDED_CLICK_WEIGHT for a best guess, 0 none; times
            PROPOSAL_CLICK_WEIGHT for a point accepted from a proposal.
        masks: optional per view (H_c, W_c) bool mask, or None for a view without one.
        masks_include_forearm: True for foreground masks that continue into the forearm (chroma key,
            and corrections of them): they are cut at the wrist before use. False for hand-only masks
            (HandSegNet predictions, masks drawn to stop at the wrist).
        keypoints_3d: optional (21, 3) metres, world frame (MVNet predictions or triangulated clicks).
        keypoint_3d_weights: optional (21,) >= 0 (e.g. MVNet confidences); default 1 where finite.
        from_proposal: optional (C, 21) bool, True where the annotator accepted the point from a proposal
            instead of placing it (its weight already carries PROPOSAL_CLICK_WEIGHT); the fit's 2D residuals
            are reported apart for those (FitDiagnostics). None: every point was placed by hand.
        points_source: "annotation" (clicks_px are annotators' points, from_proposal marking the accepted
            ones) or "detector" (the pretrained detector's keypoints: none placed by hand).
    """

    clicks_px: np.ndarray
    click_weights: np.ndarray
    masks: tuple[np.ndarray | None, ...] | None = None
    masks_include_forearm: bool = True
    keypoints_3d: np.ndarray | None = None
    keypoint_3d_weights: np.ndarray | None = None
    from_proposal: np.ndarray | None = None
    points_source: str = "annotation"

    @classmethod
    def empty(cls, num_views: int) -> FrameObservations:
        return cls(np.full((num_views, NUM_KEYPOINTS, 2), np.nan), np.zeros((num_views, NUM_KEYPOINTS)))

    def validate(self, cameras: list[Camera], margin_px: float = 0.5) -> FrameObservations:
        """Check shapes, finiteness, image bounds and that there is enough to fit; return self."""
        C = len(cameras)
        clicks = np.asarray(self.clicks_px, dtype=np.float64)
        weights = np.asarray(self.click_weights, dtype=np.float64)
        if clicks.shape != (C, NUM_KEYPOINTS, 2):
            raise FitInputError(f"clicks_px must have shape ({C}, {NUM_KEYPOINTS}, 2), got {clicks.shape}")
        if weights.shape != (C, NUM_KEYPOINTS):
            raise FitInputError(f"click_weights must have shape ({C}, {NUM_KEYPOINTS}), got {weights.shape}")
        if not np.all(np.isfinite(weights)) or np.any(weights < 0):
            raise FitInputError("click_weights must be finite and non-negative")
        if self.points_source not in POINTS_SOURCES:
            raise FitInputError(f"points_source must be one of {POINTS_SOURCES}, got {self.points_source!r}")
        if self.from_proposal is not None and np.shape(self.from_proposal) != (C, NUM_KEYPOINTS):
            raise FitInputError(f"from_proposal must have shape ({C}, {NUM_KEYPOINTS}), "
                                f"got {np.shape(self.from_proposal)}")
        used = weights > 0
        if not np.all(np.isfinite(clicks[used])):
            c, k = np.argwhere(used & ~np.isfinite(clicks).all(-1))[0]
            raise FitInputError(f"click of keypoint {k} in view {cameras[c].name} is not a finite number")
        for c, cam in enumerate(cameras):
            xy = clicks[c][used[c]]
            outside = (xy[:, 0] < -margin_px) | (xy[:, 0] > cam.width - 1 + margin_px) | \
                      (xy[:, 1] < -margin_px) | (xy[:, 1] > cam.height - 1 + margin_px)
            if outside.any():
                raise FitInputError(f"a click in view {cam.name} lies outside its {cam.width}x{cam.height} image")
        has_3d = False
        if self.keypoints_3d is not None:
            kp3d = np.asarray(self.keypoints_3d, dtype=np.float64)
            if kp3d.shape != (NUM_KEYPOINTS, 3):
                raise FitInputError(f"keypoints_3d must have shape ({NUM_KEYPOINTS}, 3), got {kp3d.shape}")
            w3 = self.keypoint_3d_weights
            if w3 is not None:
                w3 = np.asarray(w3, dtype=np.float64)
                if w3.shape != (NUM_KEYPOINTS,) or not np.all(np.isfinite(w3)) or np.any(w3 < 0):
                    raise FitInputError("keypoint_3d_weights must be 21 finite non-negative numbers")
            active = np.isfinite(kp3d).all(1) & (w3 > 0 if w3 is not None else True)
            if np.any(np.isinf(kp3d)) or np.abs(kp3d[active]).max(initial=0) > 100:
                raise FitInputError("keypoints_3d contain infinite or implausible (> 100 m) coordinates")
            has_3d = int(active.sum()) >= 3
        views_with_clicks = int((used.sum(axis=1) > 0).sum())
        if not used.any() and not has_3d:
            raise FitInputError("no clicks and no 3D keypoints: nothing to fit")
        if not has_3d and views_with_clicks < 2:
            raise FitInputError("clicks in at least two views are needed to place the hand in 3D; "
                                f"got clicks in {views_with_clicks} view")
        if self.masks is not None:
            if len(self.masks) != C:
                raise FitInputError(f"expected {C} masks (one per view), got {len(self.masks)}")
            for mask, cam in zip(self.masks, cameras, strict=True):
                if mask is None:
                    continue
                if mask.shape != (cam.height, cam.width):
                    raise FitInputError(f"mask of view {cam.name} has size {mask.shape[1]}x{mask.shape[0]}, "
                                        f"the camera's image is {cam.width}x{cam.height}")
        return self
