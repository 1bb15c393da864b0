from __future__ import annotations

from fastapi import APIRouter

from backend.api.deps import AdminUser, JobQueueDep, SessionDep, SettingsDep
from backend.models.review import Round
from backend.schemas.admin import ReviewQueueBuilt, RoundCreate, RoundLaunched, RoundPublic, Statistics
from backend.schemas.base import Id
from backend.services.review import precision_target, review
from backend.services.review.verification import HeuristicThresholds, ReviewPolicy
from backend.services.rounds import rounds

router = APIRouter(prefix="/admin/rounds", tags=["admin: rounds"])


@router.get("", response_model=list[RoundPublic])
def list_rounds(session: SessionDep, _admin: AdminUser) -> list[Round]:
    return rounds.list_rounds(session)


@router.post("", response_model=RoundLaunched, status_code=201)
def launch_round(body: RoundCreate, session: SessionDep, settings: SettingsDep, queue: JobQueueDep,
                 admin: AdminUser) -> RoundLaunched:
    """Complete the open round and launch the next: its job trains, predicts, fits and verifies. 409 (nothing
    written) while fewer labels are accepted than a round trains on (HANDLOOP_ROUND_MIN_TRAINING_SAMPLES)."""
    round_, job = rounds.launch(session, queue, admin.id, body.mvnet_version, body.handsegnet_version, body.note,
                                settings.round_min_training_samples)
    # The heuristic's thresholds for the round: the paper's, or chosen to meet the precision target (issue 40).
    precision_target.choose_for_round(session, round_, HeuristicThresholds.from_settings(settings))
    return RoundLaunched(round=RoundPublic.model_validate(round_), job_id=job.id)


@router.post("/{round_id}/cancel", response_model=RoundPublic)
def cancel_round(round_id: Id, session: SessionDep, queue: JobQueueDep, admin: AdminUser) -> Round:
    return rounds.cancel(session, queue, round_id, admin.id)


@router.get("/statistics", response_model=Statistics)
def statistics(session: SessionDep, _admin: AdminUser) -> Statistics:
    """Samples by state; per round, samples added by stream and |D_{i+1}|."""
    return rounds.statistics(session)


@router.post("/review-queue", response_model=ReviewQueueBuilt)
def build_review_queue(session: SessionDep, settings: SettingsDep, admin: AdminUser) -> ReviewQueueBuilt:
    """Apply the reviewer-queue policy to the fitted samples the heuristic did not accept."""
    return ReviewQueueBuilt(queued=review.build_queue(session, ReviewPolicy.from_settings(settings), admin.id))
