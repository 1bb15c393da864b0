"""The admin dashboard's figures beyond the round statistics: queue lengths, MVNet's confidence
histogram, its sparsification curve against the accepted fits, and human time per action."""

from __future__ import annotations

from typing import Any

import numpy as np
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.models.audit import AuditEvent
from backend.models.capture import Sample
from backend.models.enums import LeaseKind, SampleState
from backend.models.fits import Fit, Prediction
from backend.services.leases import annotation_flags, queues
from backend.services.rounds import rounds
from backend.services.statistics import activity
from backend.viewer.hand_mesh import hand_model_label
from workers.nets.sparsification import sparsification

# The paper's prices of human time ("FreiHAND Dataset", "Evaluation of Iterative Labeling").
PAPER_SECONDS = {"keypoint": 2.0, "mask": 12.0, "verification": 5.0}
HISTOGRAM_BINS = 20
SPARSIFICATION_STEPS = 20


def confidence_histogram(session: Session) -> dict[str, Any]:
    """Mean MVNet confidence of every sample that has one (the detector's frame confidence for samples
    pre-annotated and not yet predicted by MVNet), in 20 bins over [0, 1]; accepted apart."""
    rows = session.execute(select(Sample.confidence, Sample.state).where(Sample.confidence.is_not(None))).all()
    edges = np.linspace(0.0, 1.0, HISTOGRAM_BINS + 1)
    conf = np.asarray([r[0] for r in rows], dtype=float)
    accepted = np.asarray([r[1] == SampleState.accepted for r in rows], dtype=bool)
    all_counts = np.histogram(conf, edges)[0] if len(conf) else np.zeros(HISTOGRAM_BINS, int)
    acc_counts = np.histogram(conf[accepted], edges)[0] if accepted.any() else np.zeros(HISTOGRAM_BINS, int)
    return {"edges": edges.round(3).tolist(), "counts": all_counts.astype(int).tolist(),
            "accepted": acc_counts.astype(int).tolist(), "n": len(conf)}


def sparsification_curve(session: Session) -> dict[str, Any] | None:
    """MVNet's error against the accepted fits (mean keypoint distance, mm), removing the least confident
    predictions first, with the oracle (largest errors first). None with fewer than 2 samples."""

    rows = session.execute(
        select(Prediction.keypoints_m, Prediction.mean_confidence, Fit.keypoints_m)
        .join(Fit, Fit.prediction_id == Prediction.id)
        .join(Sample, (Sample.id == Fit.sample_id) & (Sample.current_fit_id == Fit.id))
        .where(Sample.state == SampleState.accepted)
    ).all()
    if len(rows) < 2:
        return None
    errors = np.asarray([np.linalg.norm(np.asarray(p) - np.asarray(f), axis=1).mean() * 1000 for p, _, f in rows])
    result = sparsification(errors, np.asarray([c for _, c, _ in rows]), steps=SPARSIFICATION_STEPS)
    return {"fractions": result.fractions.round(4).tolist(), "curve_mm": result.curve.round(3).tolist(),
            "oracle_mm": result.oracle.round(3).tolist(), "ause_mm": round(result.ause, 3), "n": len(rows)}


def human_time(session: Session, limit: int = 5000) -> dict[str, Any]:
    """Seconds per keypoint, per mask correction and per verification from the newest activity logs."""
    summaries = [(context, data.get("summary") or {}) for context, data in (
        (d.get("context"), d) for (d,) in session.execute(
            select(AuditEvent.data).where(AuditEvent.action == activity.ACTION)
            .order_by(AuditEvent.id.desc()).limit(limit)))]
    annotate = [s for c, s in summaries if c == "annotate"]
    review = [s for c, s in summaries if c == "review"]

    def ratio(total_key: str, count_key: str, rows: list[dict]) -> float | None:
        count = sum(r.get(count_key, 0) for r in rows)
        return round(sum(r.get(total_key, 0.0) for r in rows) / count, 3) if count else None

    return {
        "seconds_per_keypoint": ratio("keypoint_s", "keypoints_set", annotate),
        "seconds_per_mask": ratio("mask_s", "masks_corrected", annotate),
        "seconds_per_verification": (round(sum(r.get("time_spent_s", 0.0) for r in review) / len(review), 3)
                                     if review else None),
        "seconds_per_annotation": (round(sum(r.get("time_spent_s", 0.0) for r in annotate) / len(annotate), 3)
                                   if annotate else None),
        "annotations": len(annotate), "verifications": len(review), "paper_seconds": PAPER_SECONDS,
    }


def fits_by_hand_model(session: Session) -> dict[str, int]:
    """How many fits each hand model made, by label ("built-in stand-in hand, not MANO" for the stand-in)."""

    out: dict[str, int] = {}
    for model_file, n in session.execute(select(Fit.model_file, func.count()).group_by(Fit.model_file)).all():
        label = hand_model_label(model_file)
        out[label] = out.get(label, 0) + int(n)
    return out


def leased_counts(session: Session) -> dict[str, int]:
    """Samples of each queue someone holds a live lease on now (on screen or prefetched)."""
    now = utcnow()
    out = {}
    for kind, state in queues.QUEUE_STATE.items():
        out[kind.value] = session.execute(select(func.count()).select_from(Sample).where(
            Sample.state == state, Sample.lease_kind == kind.value, Sample.lease_expires_at > now)).scalar_one()
    return out


def dashboard(session: Session, min_training_samples: int = 1) -> dict[str, Any]:
    by_model = fits_by_hand_model(session)
    leased = leased_counts(session)
    return {
        "queues": {"annotate": queues.queue_length(session, LeaseKind.annotate),
                   "review": queues.queue_length(session, LeaseKind.review),
                   "annotate_leased": leased["annotate"], "review_leased": leased["review"]},
        "launch": {"accepted": rounds.accepted_labels(session), "minimum": min_training_samples,
                   "refusal": rounds.launch_refusal(session, min_training_samples)},
        "fits": sum(by_model.values()),
        "fits_by_hand_model": by_model,
        "confidence_histogram": confidence_histogram(session),
        "sparsification": sparsification_curve(session),
        "human_time": human_time(session),
        "flags": annotation_flags.counts(session),
    }
