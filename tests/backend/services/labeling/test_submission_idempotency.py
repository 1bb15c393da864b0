"""Idempotent submissions under concurrency, the ON CONFLICT backstop, and the audit rows of the hot path,
on both backends."""

from __future__ import annotations

import json
import uuid

from sqlalchemy import text

from backend.db.base import utcnow
from backend.models.enums import LeaseKind, Role
from backend.models.users import User
from backend.schemas.tasks import SubmissionCreate
from backend.services.accounts.users import create_user
from backend.services.captures.seed import seed_samples
from backend.services.captures.storage import LocalDiskStorage
from backend.services.jobs.jobs import InMemoryJobQueue
from backend.services.labeling import submissions
from backend.services.leases import queues
from tests.support.concurrency import all_at_once

N_THREADS = 8


def _body(session, sample_id: int, token: str, client_id: str) -> SubmissionCreate:
    view_ids = session.execute(text("SELECT id FROM views WHERE sample_id = :s ORDER BY id"),
                               {"s": sample_id}).scalars()
    clicks = [{"view_id": v, "keypoint": k, "x": 5.0, "y": 6.0} for v in view_ids for k in (0, 4)]
    return SubmissionCreate.model_validate({"submission_id": client_id, "lease_token": token, "time_spent_s": 1.0,
                                           "clicks": clicks})


def test_concurrent_duplicates_write_once(db_url, engine_factory, tmp_path):
    factory = engine_factory(db_url)
    with factory() as s, s.begin():
        (sid,) = seed_samples(s, frames=1, cameras=2)
        uid = create_user(s, "a@x.org", "password-123", Role.annotator).id
    with factory() as s, s.begin():
        lease = queues.acquire(s, s.get(User, uid), LeaseKind.annotate, 60)
        body = _body(s, sid, lease.token, "twin-" + uuid.uuid4().hex[:12])
    queue, storage = InMemoryJobQueue(), LocalDiskStorage(tmp_path)
    def submit(release) -> submissions.SubmitResult:
        with factory() as s:
            user = s.get(User, uid)
            s.commit()
            release()
            with s.begin():
                return submissions.submit(s, queue, storage, user, sid, body, 100)

    results = all_at_once(N_THREADS, submit)
    assert sorted(r.duplicate for r in results) == [False] + [True] * (N_THREADS - 1)
    assert len({r.submission.id for r in results}) == 1
    with factory() as s:
        counts = s.execute(text("SELECT (SELECT count(*) FROM submissions), (SELECT count(*) FROM clicks),"
                                " (SELECT count(*) FROM jobs)")).one()
        assert tuple(counts) == (1, 4, 1)
        assert s.execute(text("SELECT state FROM samples")).scalar_one() == "fitting"


def test_insert_on_conflict_returns_nothing_for_a_taken_client_id(db_url, engine_factory):
    factory = engine_factory(db_url)
    with factory() as s, s.begin():
        sids = seed_samples(s, frames=2, cameras=1)
        uid = create_user(s, "a@x.org", "password-123", Role.annotator).id
    values = {"client_id": "same-client-id", "user_id": uid, "time_spent_s": 1.0, "n_clicks": 0, "n_masks": 0,
              "fit_job_id": None, "created_at": utcnow()}
    with factory() as s, s.begin():
        first = submissions._insert_submission(s, {**values, "sample_id": sids[0]})
        assert first is not None
        assert submissions._insert_submission(s, {**values, "sample_id": sids[1]}) is None
    with factory() as s:
        assert s.execute(text("SELECT count(*) FROM submissions")).scalar_one() == 1


def test_next_and_submit_write_their_audit_rows(env, h):
    (sid,) = h.seed(env, frames=1, cameras=2)
    task = h.next_task(env)
    data = env.client.post(f"/api/annotate/samples/{sid}/submissions", json=h.body(task),
                           headers=env.headers(Role.annotator)).json()
    uid = env.user_ids[Role.annotator]
    with env.session() as s:
        rows = s.execute(text("SELECT actor_id, action, entity, entity_id, data FROM audit_events ORDER BY id")).all()
    got = [(r[0], r[1], r[2], r[3], r[4] if isinstance(r[4], dict) else json.loads(r[4])) for r in rows]
    assert got == [
        (uid, "lease.acquire", "sample", str(sid), {"kind": "annotate"}),
        (uid, "job.create", "job", str(data["fit_job_id"]), {"kind": "fit", "sample_id": sid}),
        (uid, "sample.state", "sample", str(sid),
         {"from": "needs_annotation", "to": "annotated", "reason": f"submission {data['id']}"}),
        (uid, "sample.state", "sample", str(sid), {"from": "annotated", "to": "fitting", "reason": "fit queued"}),
        (uid, "submission.create", "sample", str(sid),
         {"submission_id": data["id"], "client_id": data["submission_id"], "clicks": 12, "masks": 0}),
    ]
