"""Agreement (issue 40): a share of annotated samples is annotated twice, blind, by two different annotators.

- Which samples: when the fit of an annotator's submission is recorded (workers.tasks.records.record_fit), a sample
  with no agreement pair yet is picked with probability `agreement_share` (a hash of the quality seed and the
  sample's id, as the audits pick: label_audits.unit_hash).
- The second look: a picked sample goes back to the annotate queue instead of to review. The first annotator gets
  an annotation flag of kind 'agreement', which the queue reads (db.statements.passed_over): the sample never goes
  back to them. Blind: the first look's draft was deleted at its submission; the sample's current fit is cleared
  while it waits (so no proposal is built from the first fit) and the annotate page is given no previous clicks
  (services.display.overlays.annotate_proposals). MVNet's prediction, if any, is offered as to anyone.
- Figures, when the second look's fit is recorded: per keypoint the 2D disagreement, the mean over views of the
  distance between the two people's points placed by hand in the same view (pixels; accepted proposals left out:
  both may have taken the same one); the 3D disagreement, the mean keypoint distance of the two fits (mm).
- The label: the fit with the lower mean 2D residual to its own clicks (the better-supported one; the first on a
  tie) becomes the sample's current fit and goes to review as every annotated fit does. Pairs whose fits lie more
  than DISPUTE_MM apart are marked disputed: that review is the third look that decides.
- Nobody to take the second look: a sample is held only while another active user with the annotator role exists
  (`others_to_annotate`; reviewers and admins may take a second look when they annotate, but a team whose only
  annotator did the first would wait on people who mostly review). Otherwise the pair is recorded 'single' (picked,
  annotated once) and the sample goes on as any annotated fit. A pair already waiting when the last other annotator
  is deactivated or leaves the role (`release_stranded`, on that change and when the next fit is recorded) goes the
  same way: the first look's fit is the label again, to review; unless someone holds the sample or has a draft of it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.models.agreement import AgreementPair
from backend.models.capture import Sample
from backend.models.drafts import Draft
from backend.models.enums import FlagKind, LeaseKind, Role, SampleState, Visibility
from backend.models.fits import Fit
from backend.models.flags import AnnotationFlag
from backend.models.labels import Click, Submission
from backend.models.users import User
from backend.services import audit
from backend.services.captures.state_machine import transition
from backend.services.review.label_audits import QualityConfig, read_config, unit_hash

DISPUTE_MM = 15.0  # two fits further apart than this (mean keypoint distance): the reviewer's look decides
NUM_KEYPOINTS = 21


def picked(config: QualityConfig, sample_id: int) -> bool:
    """Whether the sample is annotated twice: with probability `agreement_share`, independently per sample."""
    return unit_hash(config.audit_seed, "agreement", sample_id) < config.agreement_share


def placed_points(session: Session, submission_id: int) -> dict[tuple[int, int], tuple[float, float]]:
    """(view id, keypoint) -> (x, y) pixels of the submission's points placed by hand (visible or occluded)."""
    rows = session.execute(select(Click.view_id, Click.keypoint, Click.x_px, Click.y_px)
                           .where(Click.submission_id == submission_id, Click.x_px.is_not(None),
                                  Click.y_px.is_not(None), Click.visibility != Visibility.not_annotated.value,
                                  Click.from_proposal.is_(False))).all()
    return {(int(v), int(k)): (float(x), float(y)) for v, k, x, y in rows}


def disagreement_2d(first: dict[tuple[int, int], tuple[float, float]],
                    second: dict[tuple[int, int], tuple[float, float]]) -> list[float | None]:
    """(21,) per keypoint the mean over views of the pixel distance between two people's points, where both placed
    it in the same view; None for a keypoint no view has from both."""
    per: list[list[float]] = [[] for _ in range(NUM_KEYPOINTS)]
    for key, (x, y) in first.items():
        other = second.get(key)
        if other is not None and 0 <= key[1] < NUM_KEYPOINTS:
            per[key[1]].append(math.hypot(x - other[0], y - other[1]))
    return [round(sum(d) / len(d), 4) if d else None for d in per]


def disagreement_3d_mm(keypoints_a_m: Any, keypoints_b_m: Any) -> float:
    """Mean distance between two fits' keypoints, (21, 3) metres each, world frame; millimetres."""
    a = np.asarray(keypoints_a_m, dtype=np.float64).reshape(NUM_KEYPOINTS, 3)
    b = np.asarray(keypoints_b_m, dtype=np.float64).reshape(NUM_KEYPOINTS, 3)
    return float(np.linalg.norm(a - b, axis=1).mean() * 1000.0)


def _residual_px(fit: Fit) -> float:
    value = (fit.diagnostics or {}).get("mean_residual_2d_px")
    return float(value) if isinstance(value, int | float) and math.isfinite(value) else math.inf


def better_fit(first: Fit, second: Fit) -> Fit:
    """The better-supported fit: the lower mean 2D residual to its own points (a fit without one loses; ties: first)."""
    return second if _residual_px(second) < _residual_px(first) else first


def others_to_annotate(session: Session, user_id: int | None) -> bool:
    """Whether an active annotator other than `user_id` exists to take a second look."""
    return session.execute(select(User.id).where(User.role == Role.annotator, User.is_active,
                                                 User.id != (user_id if user_id is not None else -1))
                           .limit(1)).first() is not None


def release_stranded(session: Session, actor_id: int | None) -> list[int]:
    """Pairs waiting for a second look that no other active annotator is left to take: the first look's fit is the
    sample's label again and the sample goes to review, the pair ends 'single', and the first annotator's agreement
    flag goes (the sample may come back to them if the review sends it back). A sample someone holds or has a draft
    of is left waiting (that person's look is under way). Returns the released samples' ids."""
    waiting = session.execute(select(AgreementPair).where(AgreementPair.state == "second_look")
                              .order_by(AgreementPair.id)).scalars().all()
    now = utcnow()
    released: list[int] = []
    for pair in waiting:
        if others_to_annotate(session, pair.first_user_id):
            continue
        sample = session.execute(select(Sample).where(Sample.id == pair.sample_id)
                                 .with_for_update(skip_locked=True)).scalar_one_or_none()
        first_fit = session.get(Fit, pair.first_fit_id) if pair.first_fit_id is not None else None
        if sample is None or sample.state != SampleState.needs_annotation or first_fit is None:
            continue
        held = sample.lease_expires_at is not None and sample.lease_expires_at > now
        drafted = session.execute(select(Draft.id).where(Draft.sample_id == sample.id,
                                                         Draft.kind == LeaseKind.annotate.value).limit(1)).first()
        if held or drafted is not None:
            continue
        _single(pair, first_fit, now)
        sample.current_fit_id = first_fit.id
        sample.pose_distance = first_fit.pose_distance
        session.execute(delete(AnnotationFlag).where(AnnotationFlag.sample_id == sample.id,
                                                     AnnotationFlag.kind == FlagKind.agreement.value))
        transition(session, sample, SampleState.in_review, actor_id,
                   reason=f"agreement: no other annotator for a second look; the first look's fit {first_fit.id}")
        audit.record(session, actor_id, "agreement.single", "sample", sample.id, agreement_id=pair.id,
                     label_fit_id=first_fit.id, released=True)
        released.append(sample.id)
    return released


def _single(pair: AgreementPair, fit: Fit, now: Any) -> None:
    pair.state = "single"
    pair.label_fit_id = fit.id
    pair.decided_at = now


def route(session: Session, sample: Sample, fit: Fit) -> bool:
    """Called where a fit of an annotator's submission is recorded, the sample in 'fitted': True when this routed the
    sample (a first look sent to another annotator, or a second look that made the pair's label and sent it to
    review); False: route it as usual."""
    submission_ids = (fit.inputs or {}).get("submission_ids") or []
    submission = session.get(Submission, int(submission_ids[-1])) if submission_ids else None
    if submission is None:
        return False
    pair = session.execute(select(AgreementPair).where(AgreementPair.sample_id == sample.id)
                           .with_for_update()).scalar_one_or_none()
    if pair is None:
        release_stranded(session, None)  # pairs left waiting when the last other annotator went
        config = read_config(session)
        if config.agreement_share <= 0 or not picked(config, sample.id):
            return False
        if not others_to_annotate(session, submission.user_id):  # nobody could take the second look: not held
            pair = AgreementPair(sample_id=sample.id, state="second_look", first_user_id=submission.user_id,
                                 first_submission_id=submission.id, first_fit_id=fit.id)
            _single(pair, fit, utcnow())
            session.add(pair)
            session.flush()
            audit.record(session, None, "agreement.single", "sample", sample.id, agreement_id=pair.id,
                         label_fit_id=fit.id, released=False)
            return False
        pair = AgreementPair(sample_id=sample.id, state="second_look", first_user_id=submission.user_id,
                             first_submission_id=submission.id, first_fit_id=fit.id)
        session.add(pair)
        session.add(AnnotationFlag(sample_id=sample.id, user_id=submission.user_id, submission_id=submission.id,
                                   kind=FlagKind.agreement.value, reason="first look of an agreement pair"))
        sample.current_fit_id = None  # blind: no proposal from the first look's fit
        transition(session, sample, SampleState.needs_annotation, None,
                   reason=f"agreement: a second, blind look by another annotator (first fit {fit.id})")
        session.flush()
        audit.record(session, None, "agreement.second_look", "sample", sample.id, agreement_id=pair.id,
                     first_fit_id=fit.id)
        return True
    if pair.state != "second_look" or submission.user_id == pair.first_user_id:
        return False
    first_fit = session.get(Fit, pair.first_fit_id) if pair.first_fit_id is not None else None
    pair.second_user_id, pair.second_submission_id, pair.second_fit_id = submission.user_id, submission.id, fit.id
    if pair.first_submission_id is not None:
        per_keypoint = disagreement_2d(placed_points(session, pair.first_submission_id),
                                       placed_points(session, submission.id))
        present = [d for d in per_keypoint if d is not None]
        pair.disagreement_px = per_keypoint
        pair.mean_px = round(sum(present) / len(present), 4) if present else None
    label = fit
    if first_fit is not None:
        pair.disagreement_mm = round(disagreement_3d_mm(first_fit.keypoints_m, fit.keypoints_m), 4)
        pair.disputed = pair.disagreement_mm > DISPUTE_MM
        label = better_fit(first_fit, fit)
    pair.label_fit_id = label.id
    pair.state = "done"
    pair.decided_at = utcnow()
    sample.current_fit_id = label.id
    sample.pose_distance = label.pose_distance
    why = "disputed: the review decides" if pair.disputed else "the better-supported fit"
    transition(session, sample, SampleState.in_review, None, reason=f"agreement: fit {label.id} ({why})")
    audit.record(session, None, "agreement.decide", "sample", sample.id, agreement_id=pair.id, label_fit_id=label.id,
                 disagreement_mm=pair.disagreement_mm, mean_px=pair.mean_px, disputed=pair.disputed)
    return True


def _mean(values: list[float]) -> float | None:
    return round(sum(values) / len(values), 4) if values else None


def _interval(values: list[float]) -> list[float] | None:
    """A 95 % interval of the mean (normal approximation); None under two values."""
    if len(values) < 2:
        return None
    mean = sum(values) / len(values)
    sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))
    half = 1.96 * sd / math.sqrt(len(values))
    return [round(mean - half, 4), round(mean + half, 4)]


def summary(session: Session) -> dict[str, Any]:
    """The agreement figures: pairs done and waiting, disputed, single (annotated once: nobody to take the second
    look); per keypoint (21) the mean 2D disagreement (px); the mean 2D (px) and 3D (mm) disagreement overall and per
    person (each annotator's pairs, first or second look)."""
    pairs = session.execute(select(AgreementPair)).scalars().all()
    done = [p for p in pairs if p.state == "done"]
    single = sum(1 for p in pairs if p.state == "single")
    per_keypoint: list[list[float]] = [[] for _ in range(NUM_KEYPOINTS)]
    people: dict[int, dict[str, list[float]]] = {}
    for p in done:
        for k, d in enumerate((p.disagreement_px or [])[:NUM_KEYPOINTS]):
            if d is not None:
                per_keypoint[k].append(float(d))
        for user_id in {p.first_user_id, p.second_user_id} - {None}:
            cell = people.setdefault(int(user_id), {"pairs": [], "px": [], "mm": []})
            cell["pairs"].append(1.0)
            if p.mean_px is not None:
                cell["px"].append(p.mean_px)
            if p.disagreement_mm is not None:
                cell["mm"].append(p.disagreement_mm)
    cells = [d for values in per_keypoint for d in values]
    return {
        "pairs": len(done), "waiting": sum(1 for p in pairs if p.state == "second_look"), "single": single,
        # Over every (pair, keypoint): its mean and a 95 % interval (normal; the cells are many and, for people
        # clicking independently, independent), to compare with the click noise people are known to have.
        "keypoint_px_mean": _mean(cells), "keypoint_px_ci95": _interval(cells),
        "disputed": sum(1 for p in done if p.disputed),
        "dispute_mm": DISPUTE_MM,
        "mean_px": _mean([p.mean_px for p in done if p.mean_px is not None]),
        "mean_mm": _mean([p.disagreement_mm for p in done if p.disagreement_mm is not None]),
        "per_keypoint_px": [_mean(d) for d in per_keypoint],
        "people": [{"user_id": user_id, "pairs": len(c["pairs"]), "mean_px": _mean(c["px"]), "mean_mm": _mean(c["mm"])}
                   for user_id, c in sorted(people.items())],
        "method": "a picked sample is annotated again, blind, by another annotator; px: points both placed by hand "
                  "in the same view; mm: mean keypoint distance of the two fits; label: the fit with the lower "
                  f"2D residual, reviewed as usual; over {DISPUTE_MM:g} mm apart: disputed, the review decides; "
                  "single: picked but annotated once, no other active annotator to take the second look (the "
                  "first look reviewed as usual; in no figure)",
    }
