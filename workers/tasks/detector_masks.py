"""The hand's mask for the annotate page after pre-annotation: each view's chroma-key mask cut at the detector fit's
wrist (`workers.fitting.masks.cut_forearm`) and kept near the fit's silhouette, stored as a new mask version of kind
"model".

A chroma-key mask holds the forearm and sleeve (IoU ~0.2 with the hand alone at 640 px), so annotators would redraw
it in every view; cut at the fitted wrist it is what the paper's annotators refine ("co-align the segmentation mask
with the hand model's wrist"). The page shows a view's newest mask; the fits keep reading the chroma-key and
corrected masks (`detection_inputs.masks_for`), so no fit changes. Views without a chroma-key mask get none.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import cv2
import numpy as np
from sqlalchemy import select

from backend.models.capture import Sample
from backend.models.enums import MaskKind
from backend.models.fits import Fit
from backend.models.labels import Mask
from workers.fitting.masks import cut_forearm
from workers.tasks.context import WorkerContext
from workers.tasks.detection_inputs import SOURCE
from workers.tasks.inputs import load_frames, newest_masks, read_mask, rig_of
from workers.tasks.records import add_mask

log = logging.getLogger(__name__)

MODEL_VERSION = "chroma key cut at the detector fit's wrist, near its silhouette"
# Pixels of the chroma key kept around the fit's silhouette, at 640 px width (scaled with the view). Measured on
# D_0 at 640 px (docs/benchmarks.md): 3 px leaves 22 of 192 views under IoU 0.5 with the true hand, against 26-34 for
# 6-15 px and 48 for the wrist cut alone.
NEAR_SILHOUETTE_PX = 3.0


def near(mask: np.ndarray, radius_px: int) -> np.ndarray:
    """(H, W) bool: pixels within `radius_px` of the mask (a disc dilation)."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius_px + 1, 2 * radius_px + 1))
    return cv2.dilate(mask.astype(np.uint8), kernel).astype(bool)


def mask_key(view_id: int, fit_id: int) -> str:
    return f"masks/model/{view_id}/fit-{fit_id}.png"


def record_hand_masks(ctx: WorkerContext, sample_ids: Sequence[int]) -> int:
    """For each sample whose current fit is a detector fit: per view with a chroma-key mask, that mask cut at the
    fit's wrist (wrist -> middle MCP as the hand's direction) and, where the fit stored its model mask, kept within
    NEAR_SILHOUETTE_PX of it, as a mask of kind "model". Idempotent (a view that has this fit's mask already is
    skipped). Returns how many masks were written."""
    written = 0
    for sample_id in sample_ids:
        with ctx.session_factory.begin() as session:
            sample = session.get(Sample, sample_id)
            fit = session.get(Fit, sample.current_fit_id) if sample and sample.current_fit_id is not None else None
            if fit is None or (fit.inputs or {}).get("source") != SOURCE:
                continue
            frame = load_frames(ctx, session, [sample_id]).get(sample_id)
            if frame is None:
                continue
            rig = rig_of(ctx, session, frame.project_id)
            chroma = newest_masks(session, list(frame.view_ids), (MaskKind.chroma_key,))
            keys = {v: mask_key(v, fit.id) for v in frame.view_ids}
            done = set(session.execute(select(Mask.view_id).where(Mask.view_id.in_(list(frame.view_ids)),
                                                                  Mask.storage_key.in_(list(keys.values())))).scalars())
            silhouettes = (fit.diagnostics or {}).get("model_mask_keys") or {}  # view id -> the fit's model mask
            keypoints = np.asarray(fit.keypoints_m, dtype=np.float64)
            wrist, direction = keypoints[0], keypoints[9] - keypoints[0]  # wrist -> middle MCP
            if not np.isfinite(keypoints[[0, 9]]).all() or np.linalg.norm(direction) < 1e-6:
                continue
            for c, (view_id, cam) in enumerate(zip(frame.view_ids, rig.cameras, strict=True)):
                row = chroma.get(view_id)
                if row is None or view_id in done:
                    continue
                shape, where = (cam.height, cam.width), f"sample {sample_id} view {c}"
                mask = read_mask(ctx, row.storage_key, shape, where)
                silhouette = (read_mask(ctx, silhouettes[str(view_id)], shape, f"{where} (fit silhouette)")
                              if str(view_id) in silhouettes else None)
                hand = cut_forearm(mask, cam, wrist, direction, model_silhouette=silhouette)
                if silhouette is not None:  # what else the chroma key holds (a held object, the sleeve) goes too
                    hand &= near(silhouette, max(1, round(NEAR_SILHOUETTE_PX * cam.width / 640)))
                add_mask(session, ctx.storage, view_id, MaskKind.model, hand, keys[view_id],
                         model_version=MODEL_VERSION)
                written += 1
    return written
