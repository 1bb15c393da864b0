"""A round's train phase shows the steps and seconds its train job counted itself: with HandSegNet's step floor or
a step cap the job's progress is not seconds over the budget, so that share times the budget would be wrong."""

from __future__ import annotations

from backend.models.enums import JobState
from backend.models.jobs import Job
from workers.tasks.round_progress import train_detail, train_message


def _job(progress: float, message: str = "", state: JobState = JobState.running) -> Job:
    return Job(kind="train", state=state, progress=progress, message=message)


def test_the_train_phase_shows_the_jobs_own_steps_and_seconds():
    # HandSegNet held open by its floor: 130 s of a 90 s budget, progress 0.83 of its schedule
    message = train_message("handsegnet", 1062, 130.4, 90.0, 1280, 0.71234)
    assert message == "training handsegnet: step 1062, 130 of 90 s, at least 1280 steps; loss 0.7123"
    assert train_detail(_job(0.83, message), "handsegnet", 90.0) == "step 1062, 130 of 90 s, at least 1280 steps"
    capped = train_message("mvnet", 412, 150.0, 7200.0, None, 4.0)
    assert train_detail(_job(0.63, capped), "mvnet", 7200.0) == "step 412, 150 of 7200 s"


def test_without_the_jobs_own_count_the_share_of_the_budget_and_the_end_states():
    assert train_detail(_job(0.5, "training"), "handsegnet", 90.0) == "45 of 90 s"
    assert train_detail(_job(0.0, "mvnet: detecting keypoints in 4 samples"), "mvnet", 240.0) == "0 of 240 s"
    # another network's message is not this one's count
    other = train_message("mvnet", 5, 1.0, 240.0, None, 1.0)
    assert train_detail(_job(0.25, other), "handsegnet", 90.0) == "22 of 90 s"
    done = train_message("handsegnet", 1280, 140.0, 90.0, 1280, 0.7)
    assert train_detail(_job(1.0, done, JobState.succeeded), "handsegnet", 90.0) == "done"
    assert train_detail(_job(0.4, done, JobState.failed), "handsegnet", 90.0) == "failed"
