"""Two estimators judging each other in rounds 1 on (docs/evaluation.md, "Cross-estimator checks").

The paper's heuristic compares a fit with the prediction it was fitted to. Round 0 left, for each sample it fitted,
an estimate that shares no input with MVNet but the images: the pretrained detector's lift and the fit made from it.
A fit from MVNet's prediction that fails the paper's heuristic is judged two more ways:
- its keypoints against the lift (`fit_against_lift`: the detector's heuristic, MVNet's fit in the detector fit's
  place);
- the pre-annotation's own fit against MVNet's prediction (`earlier_fit_against_prediction`: MVNet in the lift's
  place). That fit is often the better of the two (round 0's fits are made with the detector's keypoints and the
  chroma key), so the sample is accepted with it.
Only a pre-annotation fit no person decided on takes part: a reviewer's judgement is never overruled.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.fits import Fit, Prediction
from backend.models.review import Decision
from backend.services.review.verification import (
    HeuristicResult,
    HeuristicThresholds,
    detector_verdict,
    heuristic_verdict,
)
from backend.settings import Settings

log = logging.getLogger(__name__)

# A pre-annotation fit's source (workers.tasks.detection_inputs.SOURCE, tested equal): not imported, since that
# module loads OpenCV and the detector's helpers, which recording a fit does not need.
DETECTOR_SOURCE = "detector"


@dataclass(frozen=True)
class EarlierFitThresholds:
    """The paper's criteria for the pre-annotation's fit against MVNet's prediction, and the lift it was made from:
    its mean confidence must be above `min_lift_confidence` (both estimators sure of themselves)."""

    fit: HeuristicThresholds
    min_lift_confidence: float


def thresholds_from_settings(settings: Settings) -> tuple[HeuristicThresholds | None, EarlierFitThresholds | None]:
    """(MVNet's fit against the lift, the pre-annotation's fit against MVNet's prediction) thresholds; None where the
    settings turn that check off. The first are the detector's heuristic's with its own mean distance."""
    cross = dataclasses.replace(HeuristicThresholds.from_settings(settings, "detector_heuristic_"),
                                max_mean_distance_m=settings.cross_heuristic_max_mean_distance_m)
    earlier = EarlierFitThresholds(HeuristicThresholds.from_settings(settings, "earlier_fit_check_"),
                                   settings.earlier_fit_check_min_lift_confidence)
    return (cross if settings.cross_heuristic else None), (earlier if settings.earlier_fit_check else None)


def detection_of(fit: Fit) -> dict[str, Any] | None:
    """The detector's lift a pre-annotation fit was made from (its inputs' "detection"); None for other fits."""
    inputs = fit.inputs or {}
    detection = inputs.get("detection") if inputs.get("source") == DETECTOR_SOURCE else None
    return detection if isinstance(detection, dict) else None


def against_lift(fit: Fit, detection: dict[str, Any], ious: Mapping[int, float],
                 thresholds: HeuristicThresholds) -> HeuristicResult | None:
    """The detector's heuristic on `fit` (21 keypoints, metres, world frame) against a stored lift; None when the
    stored lift is malformed (a person looks instead)."""
    try:
        return detector_verdict(detection.get("confidence"), ious.values(), detection.get("points_world"),
                                fit.keypoints_m, thresholds)
    except (TypeError, ValueError) as exc:
        log.warning("fit %s: detector heuristic not applied: %s", fit.id, exc)
        return None


def pre_annotation_fit(session: Session, fit: Fit) -> Fit | None:
    """The sample's latest pre-annotation fit other than `fit`, if no person decided on it; else None."""
    for earlier in session.scalars(select(Fit).where(Fit.sample_id == fit.sample_id, Fit.id != fit.id)
                                   .order_by(Fit.id.desc())):
        if detection_of(earlier) is None:
            continue
        judged = session.execute(select(Decision.id).where(Decision.fit_id == earlier.id,
                                                           Decision.user_id.is_not(None)).limit(1)).first()
        return None if judged is not None else earlier
    return None


def fit_against_lift(earlier: Fit, fit: Fit, ious: Mapping[int, float], thresholds: HeuristicThresholds
                     ) -> HeuristicResult | None:
    """MVNet's fit (`fit`, its view IoUs `ious`) against the lift `earlier` was made from."""
    detection = detection_of(earlier)
    return None if detection is None else against_lift(fit, detection, ious, thresholds)


def earlier_fit_against_prediction(earlier: Fit, prediction: Prediction, thresholds: EarlierFitThresholds
                                   ) -> HeuristicResult | None:
    """The paper's three criteria on the pre-annotation's fit with MVNet's prediction as the estimate: MVNet's
    confidences, the earlier fit's view IoUs (against the chroma-key cut), its keypoints against MVNet's; and the
    lift's mean confidence. None when the earlier fit has no view IoUs or lift."""
    detection = detection_of(earlier)
    if not earlier.view_ious or detection is None:
        return None
    verdict = heuristic_verdict(prediction.confidences, earlier.view_ious.values(), prediction.keypoints_m,
                                earlier.keypoints_m, thresholds.fit)
    lifted = np.array(detection.get("confidence") or [], dtype=np.float64)  # None -> NaN: not lifted
    # rounded as heuristic_verdict rounds its means: 21 x 0.4 averages to 0.4 exactly, not 0.4000000000000001
    lift_confidence = round(float(np.nanmean(lifted)), 12) if np.isfinite(lifted).any() else 0.0
    failed = list(verdict.failed)
    if not lift_confidence > thresholds.min_lift_confidence:
        failed.append(f"the lift's mean confidence {lift_confidence:.3f} is not above {thresholds.min_lift_confidence}")
    return HeuristicResult(not failed, tuple(failed), {**verdict.metrics, "lift_confidence": lift_confidence})
