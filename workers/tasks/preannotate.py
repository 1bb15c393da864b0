"""Pre-annotation jobs (issue 15: round 0 without clicks).

For each of the job's samples still 'unlabeled': the pretrained detector's per-view 2D keypoints, lifted over
the views (`workers.detector.detect_frame`) -> a fit job of source "detector", whose input is the inlier views'
detections as 2D keypoints weighted by their confidence, plus the masks the annotation fits use -> the fit
(workers.tasks.fits, the round-0 weights) -> the reviewers' queue by the paper's policy
(services.review.verification.select_for_review: every fit, ranked, up to the reviewers' capacity), the detector's
frame confidence standing in for MVNet's. The samples the policy does not pick, those where no hand was
found and those whose fit failed go to the annotators (payload "rest": "annotate"; failed fits always do, as
for every fit) or stay 'unlabeled' / 'fitted' ("keep"); annotators then see the fit's and the detector's
keypoints as proposals ("F", "D") and, per view, the chroma-key mask cut at the fit's wrist
(workers.tasks.detector_masks) instead of hand and forearm.

The detector core is reached only through `detect` here and `services.rounds.preannotation.detector_problem`
(tests swap in fakes). A job is
claimed like every other; a redelivered one continues from what is recorded: a sample with its fit job
already made is not detected again, and the routing only moves samples still 'fitted'.
"""

from __future__ import annotations

import logging
import time
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.capture import Sample
from backend.models.enums import JobKind, JobState, SampleState
from backend.models.fits import Fit
from backend.models.jobs import Job
from backend.services.captures.state_machine import transition
from backend.services.errors import DomainError
from backend.services.jobs import jobs
from backend.services.review.verification import Candidate, ReviewPolicy, select_for_review
from backend.services.rounds import preannotation
from workers.capture.reader import load_frame_images
from workers.capture.schema import CaptureError
from workers.detector.handedness import side_disagreement
from workers.detector.types import DetectorInputError, DetectorUnavailableError, Handedness, LiftedKeypoints
from workers.geometry.camera import Camera
from workers.rigs.hand_scale import estimate_hand_scale, hand_scale_of_views
from workers.tasks import records
from workers.tasks.context import WorkerContext
from workers.tasks.detection_inputs import SOURCE, detection_record, lifted_count, masks_for
from workers.tasks.detector_masks import record_hand_masks
from workers.tasks.fits import run_fit_jobs
from workers.tasks.inputs import NUM_KEYPOINTS, InputError, Rig, SampleFrame, load_frames, rig_of
from workers.tasks.progress import JobCancelledError, ProgressReporter
from workers.tasks.working_inputs import lifted_at_full_resolution, working_frame, working_masks, working_rig

log = logging.getLogger(__name__)

MIN_LIFTED_KEYPOINTS = 6  # fewer keypoints lifted to 3D: no hand to place (the fit needs a placement)
CHUNK_IN = 500  # ids per IN (...) clause


# --- the one seam to the detector core ------------------------------------------------------------------


def detect(images: Sequence[np.ndarray], cameras: Sequence[Camera], masks: Sequence[np.ndarray | None] | None,
           *, handedness: Handedness = "right") -> LiftedKeypoints:
    """`workers.detector.detect_frame`: images (H, W, 3) uint8 RGB and masks (H, W) bool or None per view, in
    calibration order."""
    from workers.detector import detect_frame  # deferred: resolving it loads the detector's pipeline (torch)

    return detect_frame(images, cameras, masks, handedness=handedness)


# --- the job --------------------------------------------------------------------------------------------


def _chunks(ids: Sequence[int], size: int = CHUNK_IN) -> list[list[int]]:
    return [list(ids[i:i + size]) for i in range(0, len(ids), size)]


def _fit_jobs_of(session: Session, job_id: int, sample_ids: Sequence[int]) -> dict[int, Job]:
    """sample id -> the fit job this pre-annotation job made for it."""
    out: dict[int, Job] = {}
    for part in _chunks(sample_ids):
        for fit_job in session.execute(select(Job).where(Job.kind == JobKind.fit, Job.sample_id.in_(part))
                                       .order_by(Job.id)).scalars():
            if (fit_job.payload or {}).get("preannotate_job_id") == job_id:
                out[fit_job.sample_id] = fit_job
    return out


def _states(session: Session, sample_ids: Sequence[int]) -> dict[int, str]:
    out: dict[int, str] = {}
    for part in _chunks(sample_ids):
        out.update(session.execute(select(Sample.id, Sample.state).where(Sample.id.in_(part))).all())
    return out


def _side(frame: SampleFrame) -> Handedness:
    """The hand of the sample's sequence, as the detector names it."""
    return "left" if frame.side == "left" else "right"


def _detect_sample(ctx: WorkerContext, frame: SampleFrame, rig: Rig, handedness: Handedness
                   ) -> tuple[dict[str, Any] | None, str]:
    """(detection record, "") or (None, why there is nothing to fit: bad input, no hand, or the detector failing
    on this frame). DetectorUnavailableError propagates: it ends the job."""

    try:
        with ctx.session_factory() as session:
            masks, mask_ids = masks_for(ctx, session, frame, rig)
            wrig = working_rig(session, rig)  # the detector reads the working copies; the record is in full pixels
        # The masks come from masks_for: only the images need working copies.
        images = load_frame_images(working_frame(ctx, frame, wrig, with_masks=False).frame, wrig.cameras)
        ordered = [images[cam.name] for cam in wrig.cameras]
        lifted = detect(ordered, wrig.cameras, working_masks(masks, wrig) if mask_ids else None, handedness=handedness)
        record = detection_record(lifted_at_full_resolution(lifted, wrig), frame.view_ids)
    except (DetectorInputError, CaptureError, InputError, KeyError) as exc:
        return None, f"detector input: {exc}"
    except DetectorUnavailableError:
        raise  # the model files went missing or corrupt: no other sample can be detected either
    except Exception as exc:  # one frame that breaks the detector must not sink the others (as for the fits)
        log.exception("detector failed on sample %s", frame.sample_id)
        return None, f"detector failed: {exc.__class__.__name__}: {exc}"
    lifted_n = lifted_count(record)
    if lifted_n < MIN_LIFTED_KEYPOINTS:
        found = sum(v is not None for v in record["views"])
        return None, (f"no hand to fit: the detector found it in {found} of {len(rig.cameras)} views and lifted "
                      f"{lifted_n} of {NUM_KEYPOINTS} keypoints (at least {MIN_LIFTED_KEYPOINTS} needed)"
                      + _scale_problem(lifted, wrig.cameras))
    size = estimate_hand_scale(lifted.points_world[None])
    if size.verdict in ("too large", "too small"):
        return None, f"no hand to fit: {size.message()}"
    return record, ""


def _scale_problem(lifted: LiftedKeypoints, cameras: Sequence[Camera]) -> str:
    """"; <why>" when the views' detections triangulate (plain DLT, no metric threshold) to a hand of no human
    size: the calibration's length unit is wrong, which is why the lift (metric thresholds) failed; else ""."""
    views = [None if v is None else v.keypoints_px for v in lifted.views]
    if sum(v is not None for v in views) < 2:
        return ""
    size = hand_scale_of_views(views, cameras)
    return f"; {size.message()}" if size.verdict in ("too large", "too small") else ""


def _queue_detector_fit(ctx: WorkerContext, job_id: int, sample_id: int, record: dict[str, Any]) -> int | None:
    """A fit job of source "detector" for a sample still 'unlabeled' (None when it no longer is)."""
    with ctx.session_factory.begin() as session:
        sample = session.get(Sample, sample_id)
        if sample is None or sample.state != SampleState.unlabeled:
            return None
        fit_job = records.queue_fit(session, ctx.job_queue, sample_id, source=SOURCE, enqueue=False,
                                    payload={"preannotate_job_id": job_id, "detection": record})
        # The policy ranks reviewers' candidates by this: the detector's confidence in MVNet's place.
        sample.confidence = float(record.get("frame_confidence") or 0.0)
        session.flush()
        return fit_job.id


def _to_annotators(session: Session, sample_ids: Sequence[int], from_state: SampleState, reason: str) -> int:
    moved = 0
    for part in _chunks(sample_ids):
        for sample in session.execute(select(Sample).where(Sample.id.in_(part), Sample.state == from_state)
                                      .with_for_update()).scalars():
            transition(session, sample, SampleState.needs_annotation, None, reason=reason)
            moved += 1
    return moved


def route_fitted(ctx: WorkerContext, job_id: int, sample_ids: Sequence[int], rest: str) -> dict[str, int]:
    """The job's samples 'fitted' from their detector fit (those the detector's heuristic did not accept): ranked by
    the detector's confidence and offered to the reviewers up to their capacity a round (`select_for_review`; the
    capacity is `preannotation_review_capacity` where set, else `review_capacity_per_round`; 0 the paper's fixed
    cut: from the median up, temporally spread); never flat
    hands. The rest go to the annotators when `rest` is "annotate", else stay fitted for round 1.

    The percentile cuts (as `review_percentile_cut` sets it) only once the heuristic gave D_0 enough labels to train
    round 1 on (`round_min_training_samples`); until then every fit is offered, D_0 being all round 1 has."""
    with ctx.session_factory.begin() as session:
        rows: list[Sample] = []
        for part in _chunks(sample_ids):
            rows += session.execute(select(Sample).where(Sample.id.in_(part), Sample.current_fit_id.is_not(None))
                                    .with_for_update()).scalars().all()
        fits = {}
        for part in _chunks([s.current_fit_id for s in rows]):
            fits.update({f.id: f for f in session.execute(select(Fit).where(Fit.id.in_(part))).scalars()})
        ours = [s for s in rows if (fits[s.current_fit_id].inputs or {}).get("preannotate_job_id") == job_id]
        verdicts = [fits[s.current_fit_id].heuristic for s in ours if fits[s.current_fit_id].heuristic]
        heuristic = {"fits": len(ours), "evaluated": len(verdicts),
                     "accepted": sum(bool(v.get("accepted")) for v in verdicts)}
        policy = ReviewPolicy.from_settings(ctx.settings)
        if (capacity := ctx.settings.preannotation_review_capacity) is not None:  # round 0's own
            policy = replace(policy, capacity=capacity or None)
        if heuristic["accepted"] < ctx.settings.round_min_training_samples:
            policy = replace(policy, percentile_cut=False)
        mine = [s for s in ours if s.state == SampleState.fitted]
        # Round 0 ranks by the detector's confidence whatever ReviewPolicy.rank says: on tuning seeds 57 and 23 its
        # fits' distance to the lift ranked them about as well (Spearman 0.50 and 0.51 against 0.58 and 0.45).
        candidates = [Candidate(s.id, s.sequence_id, s.time_s, s.confidence, s.pose_distance or 0.0) for s in mine]
        queued: dict[int, list[float]] = {}
        for sequence_id, time_s in session.execute(select(Sample.sequence_id, Sample.time_s)
                                                   .where(Sample.state == SampleState.in_review)):
            queued.setdefault(sequence_id, []).append(time_s)
        picked = set(select_for_review(candidates, policy, queued))
        for sample in mine:
            if sample.id in picked:
                transition(session, sample, SampleState.in_review, None, reason="review policy (pre-annotation)")
            elif rest == "annotate":
                transition(session, sample, SampleState.needs_annotation, None,
                           reason="pre-annotation: not picked for review; annotators correct the detector's fit")
    return {"to_review": len(picked), "fitted_to_annotators": (len(mine) - len(picked)) if rest == "annotate" else 0,
            "heuristic": heuristic}


def _settle(ctx: WorkerContext, job_id: int, sample_ids: Sequence[int], rest: str, *, cancel_fits: bool
            ) -> dict[str, int]:
    """Leave no sample of the job in between: cancel its unfinished fit jobs (when stopping early), route the
    fitted samples, and when `rest` is "annotate" hand those still 'unlabeled' to the annotators (the
    paper-only path, as without the detector)."""
    with ctx.session_factory.begin() as session:
        if cancel_fits:
            for fit_job in _fit_jobs_of(session, job_id, sample_ids).values():
                if JobState(fit_job.state) not in jobs.FINAL_STATES:
                    jobs.cancel(session, ctx.job_queue, fit_job.id, None)
    routed = route_fitted(ctx, job_id, sample_ids, rest)
    with ctx.session_factory.begin() as session:
        left = [s for s, state in _states(session, sample_ids).items() if state == SampleState.unlabeled]
        moved = _to_annotators(session, left, SampleState.unlabeled,
                               "pre-annotation: no detector fit; annotators click") if rest == "annotate" else 0
    return {**routed, "unlabeled_to_annotators": moved}


def run_preannotation_job(ctx: WorkerContext, job_id: int) -> dict[str, Any]:
    """Claim a preannotate job (payload: project_id, sample_ids, rest, handedness) and run it; returns its
    result (also stored on the job). Without a handedness in the payload the detector looks for each sample's
    sequence's hand (`SampleFrame.side`)."""

    started = time.perf_counter()
    with ctx.session_factory.begin() as session:
        job = ctx.claim(session, job_id)
        if job is None:
            return {"job_id": job_id, "skipped": True}
        payload = dict(job.payload or {})
        sample_ids = [int(s) for s in payload.get("sample_ids", [])]
        rest = str(payload.get("rest", "annotate"))
        chosen = payload.get("handedness")
        handedness: Handedness | None = chosen if chosen in ("right", "left") else None
        project_id = payload.get("project_id")
        problem = preannotation.detector_problem()
        if problem is None:
            problem = (f"rest must be one of {preannotation.RESTS}, not {rest!r}" if rest not in preannotation.RESTS
                       else preannotation.project_problem(session, int(project_id)) if isinstance(project_id, int)
                       else f"preannotate job {job_id} names no project")
        if problem:  # nothing was written for any sample: the paper-only path is untouched
            jobs.finish(session, job_id, JobState.failed, error=problem[:2000])
            return {"job_id": job_id, "failed": problem}
    summary: dict[str, Any] = {"samples": len(sample_ids), "detected": 0, "no_detection": 0, "fitted": 0,
                               "fit_failed": 0, "errors": {}}
    reporter = ProgressReporter(ctx, [job_id])
    size = max(1, ctx.settings.fit_batch_size)
    looks: dict[str, list[Any]] = defaultdict(lambda: ["right", []])  # sequence -> [side asked for, frames' sides]
    try:
        with ctx.session_factory() as session:
            earlier = _fit_jobs_of(session, job_id, sample_ids)
            states = _states(session, sample_ids)
        leftover = [j.id for j in earlier.values() if JobState(j.state) not in jobs.FINAL_STATES]
        if leftover:  # a redelivered job: the fits an earlier attempt queued but did not run
            _tally(summary, run_fit_jobs(ctx, leftover, parent=(job_id, 0.0, 0.05)))
        todo = [s for s in sample_ids if states.get(s) == SampleState.unlabeled and s not in earlier]
        for start in range(0, len(todo), size):
            part = todo[start:start + size]
            span = (0.05 + 0.9 * start / len(todo), 0.05 + 0.9 * (start + len(part)) / len(todo))
            reporter(span[0], f"detecting hands: {start}/{len(todo)} samples", force=True)
            fit_job_ids = []
            with ctx.session_factory() as session:
                frames = load_frames(ctx, session, part)
                rig = rig_of(ctx, session, int(project_id))
            for i, sample_id in enumerate(part):
                _stop_if_cancelled(ctx, job_id)
                frame = frames.get(sample_id)
                record, why = (_detect_sample(ctx, frame, rig, handedness or _side(frame)) if frame
                               else (None, "sample is gone"))
                if record is not None and frame is not None:  # the side the detected hand looks like, per sequence
                    looks[frame.sequence_key][0] = handedness or _side(frame)
                    looks[frame.sequence_key][1].append(record.get("hand_side"))
                reporter(span[0] + (span[1] - span[0]) * 0.5 * (i + 1) / len(part),
                         f"detecting hands: {start + i + 1}/{len(todo)} samples")
                if record is None:
                    summary["no_detection"] += 1
                    summary["errors"][str(sample_id)] = why[:300]
                    continue
                fit_job_id = _queue_detector_fit(ctx, job_id, sample_id, record)
                if fit_job_id is not None:
                    summary["detected"] += 1
                    fit_job_ids.append(fit_job_id)
            if fit_job_ids:
                mid = span[0] + 0.5 * (span[1] - span[0])
                _tally(summary, run_fit_jobs(ctx, fit_job_ids, parent=(job_id, mid, span[1])))
    except JobCancelledError:
        summary.update(_settle(ctx, job_id, sample_ids, rest, cancel_fits=True), cancelled=True)
        return {"job_id": job_id, **summary}
    except (DetectorUnavailableError, DomainError, InputError, CaptureError, ValueError) as exc:
        message = getattr(exc, "message", None) or str(exc) or exc.__class__.__name__
        log.warning("preannotate job %s failed: %s", job_id, message)
        summary.update(_settle(ctx, job_id, sample_ids, rest, cancel_fits=True))
        with ctx.session_factory.begin() as session:
            jobs.finish(session, job_id, JobState.failed, error=message[:2000], result=_jsonable(summary))
        return {"job_id": job_id, "failed": message, **summary}
    _note_side_disagreement(job_id, looks, summary)
    try:  # before routing: the annotate page shows a view's newest mask
        summary["hand_masks"] = record_hand_masks(ctx, sample_ids)
    except Exception as exc:  # the page then shows the chroma key, as before: no reason to fail the job
        log.exception("preannotate job %s: hand masks not recorded", job_id)
        summary["errors"]["hand masks"] = f"{exc.__class__.__name__}: {exc}"[:300]
    summary.update(_settle(ctx, job_id, sample_ids, rest, cancel_fits=False))
    summary["seconds"] = round(time.perf_counter() - started, 3)
    result = _jsonable(summary)
    with ctx.session_factory.begin() as session:
        jobs.finish(session, job_id, JobState.succeeded, result=result)
    log.info("preannotate job %s done: %s", job_id, {k: v for k, v in result.items() if k != "errors"})
    return {"job_id": job_id, **result}


def _note_side_disagreement(job_id: int, looks: dict[str, list[Any]], summary: dict[str, Any]) -> None:
    """Where a sequence's detected hands look like the other side than the one the detector was asked for
    (workers.detector.handedness.side_disagreement), say so in the job's result ("handedness" per sequence) and
    the log: the capture's declared side may be wrong, or the detector took the other hand."""
    notes = {key: note for key, (side, sides) in looks.items() if (note := side_disagreement(sides, side))}
    if notes:
        summary["handedness"] = notes
        for key, note in notes.items():
            log.warning("preannotate job %s, sequence %s: %s", job_id, key, note)


def _stop_if_cancelled(ctx: WorkerContext, job_id: int) -> None:
    """Raise JobCancelledError once the job is final (cancelled by an admin): checked before each sample, as
    the progress writes that would notice it are spaced in time."""
    with ctx.session_factory() as session:
        if jobs.is_final(session, job_id):
            raise JobCancelledError(f"preannotate job {job_id} cancelled")


def _tally(summary: dict[str, Any], part: Any) -> None:
    summary["fitted"] += len(part.fitted)
    summary["fit_failed"] += len(part.failed)
    summary["errors"].update({f"fit job {k}": v[:300] for k, v in part.failed.items()})


def _jsonable(summary: dict[str, Any]) -> dict[str, Any]:
    errors = dict(list(summary.get("errors", {}).items())[:50])  # a job row is no log: the first 50 reasons
    return {**summary, "errors": errors}
