"""The preannotate task on a real worker process (embedded broker): the task name, its queue and the service
are wired up. Where this build cannot run the detector (its code or model files missing), the job fails with
the detector's own sentence and changes no sample; where it can, it pre-annotates the samples."""

from __future__ import annotations

from sqlalchemy import func, select


def test_a_preannotate_job_reaches_the_worker_and_ends_as_the_detector_allows(live_stack):
    from backend.broker.celery_queue import CeleryJobQueue
    from backend.models.capture import Project, Sample
    from backend.models.enums import JobKind
    from backend.models.fits import Fit
    from backend.services.jobs import jobs
    from backend.services.jobs.jobs import InMemoryJobQueue
    from backend.services.rounds.preannotation import detector_problem

    stack = live_stack(frames=2, queue_for_annotation=False)
    factory = stack.session_factory()
    with factory.begin() as session:
        project_id = session.execute(select(Project.id)).scalar_one()
        sample_ids = list(session.execute(select(Sample.id).order_by(Sample.id)).scalars())
        job_id = jobs.create(session, InMemoryJobQueue(), JobKind.preannotate, enqueue=False,
                             payload={"project_id": project_id, "sample_ids": sample_ids, "rest": "keep"}).id
    assert CeleryJobQueue(stack.settings).send(job_id, "preannotate")
    job = stack.wait_for_job(job_id)
    with factory() as session:
        states = dict(session.execute(select(Sample.state, func.count()).group_by(Sample.state)).all())
        fits = session.execute(select(func.count()).select_from(Fit)).scalar_one()
    problem = detector_problem()  # the worker runs this install, so it answers the same
    if problem is not None:
        assert job["state"] == "failed" and job["error"] == problem, job
        assert states == {"unlabeled": 2} and fits == 0
    else:
        assert job["state"] == "succeeded" and job["result"]["samples"] == 2, job
        assert "unlabeled" not in states or job["result"]["no_detection"] > 0
