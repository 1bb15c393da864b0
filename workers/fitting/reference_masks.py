"""The mask a fit from MVNet's prediction is compared with (its silhouette term, and so the paper's heuristic's
IoU criterion), per view: one rule for the bootstrap round (workers.tasks.inputs.from_prediction) and for
`handloop bench mvnet-precision`, so the bench measures the heuristic the loop runs."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from workers.fitting.masks import cut_forearm
from workers.geometry.camera import Camera
from workers.geometry.projection import project_points

REFERENCES = ("chroma_key", "handsegnet")
# How far behind the predicted wrist keypoint the chroma-key reference keeps pixels: the hand model's mesh
# reaches 2.6-2.7 cm behind its wrist keypoint along the hand axis (1st percentile / minimum of the built-in
# hand's vertices, synthetic capture seed 0); cutting at 4 mm as the fit's own cut does would leave ~2 cm of
# correct fit outside the reference (true-hand IoU 0.73 vs 0.79 at 2 cm on that frame's 8 views, 320 px).
REFERENCE_WRIST_MARGIN_M = 0.02


def prediction_reference_masks(handsegnet: Sequence[np.ndarray | None], chroma: Sequence[np.ndarray | None],
                               cameras: Sequence[Camera], keypoints_m: np.ndarray,
                               reference: str = "chroma_key"
                               ) -> tuple[list[np.ndarray | None], list[str | None], bool]:
    """Per view the mask a prediction's fit (its silhouette term, and so the heuristic's IoU) is compared with.

    reference "chroma_key" (setting `heuristic_iou_reference`): a view with a chroma-key mask gets that mask
    cut at the wrist along MVNet's predicted hand axis (wrist keypoint 0 -> middle-finger base keypoint 9,
    FreiHAND order) by `cut_forearm`, the cylinder cut the annotation fits use, but placed by the prediction,
    never by the fit being judged, and REFERENCE_WRIST_MARGIN_M behind the wrist, where the hand model ends;
    views looking along that axis (where the cylinder cut is ill-posed) keep the chroma pixels within 15 px
    (at 320 px width) of the predicted keypoints' convex hull. Other views get
    HandSegNet's mask, or none. reference "handsegnet" (the paper): HandSegNet's masks; where HandSegNet found
    no hand in any view, the chroma-key masks uncut, for the fit to cut at its own wrist.

    Args:
        handsegnet: C (H, W) bool masks or None.
        chroma: C (H, W) bool chroma-key foreground masks (hand and forearm) or None.
        cameras: the C cameras, same order.
        keypoints_m: (21, 3) MVNet's keypoints, metres, world frame, FreiHAND order.
        reference: "chroma_key" or "handsegnet".
    Returns:
        C masks (bool (H, W) or None), C sources ("chroma_key_cut", "handsegnet", "chroma_key" or None),
        and whether the masks include the forearm (the fit's `masks_include_forearm`).
    """
    if reference not in REFERENCES:
        raise ValueError(f"heuristic_iou_reference must be 'chroma_key' or 'handsegnet', not {reference!r}")
    if reference == "handsegnet":
        if any(m is not None for m in handsegnet):
            return list(handsegnet), ["handsegnet" if m is not None else None for m in handsegnet], False
        return list(chroma), ["chroma_key" if m is not None else None for m in chroma], True
    kp = np.asarray(keypoints_m, dtype=np.float64)
    pixels, _ = project_points(kp, list(cameras))  # (C, 21, 2)
    masks: list[np.ndarray | None] = []
    sources: list[str | None] = []
    for c, cam in enumerate(cameras):
        if chroma[c] is not None and np.any(chroma[c]):
            hull = np.zeros((cam.height, cam.width), dtype=np.uint8)
            if np.all(np.isfinite(pixels[c])):
                cv2.fillConvexPoly(hull, cv2.convexHull(np.round(pixels[c]).astype(np.int32)), 1)
            masks.append(cut_forearm(np.asarray(chroma[c], dtype=bool), cam, kp[0], kp[9] - kp[0],
                                     margin_m=REFERENCE_WRIST_MARGIN_M, model_silhouette=hull.astype(bool)))
            sources.append("chroma_key_cut")
        elif handsegnet[c] is not None:
            masks.append(np.asarray(handsegnet[c], dtype=bool))
            sources.append("handsegnet")
        else:
            masks.append(None)
            sources.append(None)
    return masks, sources, False  # both kinds stop at the wrist
