"""PostgreSQL: everything a submission writes after its lock, in one statement (one round trip instead of six).

Data-modifying CTEs: the fit job row, the submission pointing at it (`ON CONFLICT (client_id) DO NOTHING`:
the unique constraint decides a concurrent twin), every click (one `unnest` of arrays, so the text does not
depend on the number of clicks and psycopg prepares it once), the sample's move to `fitting` with its
lease cleared, the four audit rows (job.create, the two state changes, submission.create, in that order)
and the deletion of the sample's annotation drafts. All but the job are gated on the submission row being
written; when it is not (a client id already used), the caller raises and the transaction, job row
included, is rolled back. SQLite runs the same writes as separate statements (services.submissions).
"""

from __future__ import annotations

import json
from datetime import datetime
from typing import Any

from sqlalchemy import Connection, bindparam, text

from backend.db.base import UTCDateTime
from backend.models.enums import JobKind, JobState, LeaseKind, SampleState, Visibility

SUBMIT = text(f"""
WITH job AS (
  INSERT INTO jobs (kind, state, progress, message, sample_id, payload, created_by_id, created_at, updated_at,
                    dispatched_at, attempts)
  VALUES ('{JobKind.fit.value}', '{JobState.queued.value}', 0.0, '', :sample_id, CAST(:payload AS json), :user_id,
          :now, :now, :now, 0)
  RETURNING id
), sub AS (
  INSERT INTO submissions (fit_job_id, client_id, sample_id, user_id, time_spent_s, n_clicks, n_masks, created_at)
  SELECT job.id, :client_id, :sample_id, :user_id, :time_spent_s, :n_clicks, :n_masks, :now FROM job
  ON CONFLICT (client_id) DO NOTHING
  RETURNING id
), clk AS (
  INSERT INTO clicks (submission_id, sample_id, view_id, keypoint, x_px, y_px, visibility, from_proposal, user_id,
                      time_spent_s, created_at)
  SELECT sub.id, :sample_id, t.view_id, t.keypoint, t.x, t.y, t.visibility, t.from_proposal, :user_id,
         :time_spent_s, :now
  FROM sub, unnest(CAST(:view_ids AS integer[]), CAST(:keypoints AS integer[]), CAST(:xs AS double precision[]),
                   CAST(:ys AS double precision[]), CAST(:visibilities AS varchar[]),
                   CAST(:from_proposals AS boolean[])) AS t(view_id, keypoint, x, y, visibility, from_proposal)
), smp AS (
  UPDATE samples SET state = '{SampleState.fitting.value}', leased_by_id = NULL, lease_kind = NULL,
                     lease_token = NULL, lease_expires_at = NULL, updated_at = :now
  WHERE id = :sample_id AND EXISTS (SELECT 1 FROM sub)
), aud AS (
  INSERT INTO audit_events (at, actor_id, action, entity, entity_id, data)
  SELECT :now, :user_id, a.action, a.entity, a.entity_id, a.data
  FROM job, sub, LATERAL (VALUES
    (1, 'job.create', 'job', CAST(job.id AS varchar),
     json_build_object('kind', '{JobKind.fit.value}', 'sample_id', CAST(:sample_id AS integer))),
    (2, 'sample.state', 'sample', CAST(:sample_id AS varchar),
     json_build_object('from', CAST(:from_state AS varchar), 'to', '{SampleState.annotated.value}',
                       'reason', 'submission ' || sub.id)),
    (3, 'sample.state', 'sample', CAST(:sample_id AS varchar),
     json_build_object('from', '{SampleState.annotated.value}', 'to', '{SampleState.fitting.value}',
                       'reason', 'fit queued')),
    (4, 'submission.create', 'sample', CAST(:sample_id AS varchar),
     json_build_object('submission_id', sub.id, 'client_id', CAST(:client_id AS varchar),
                       'clicks', CAST(:n_clicks AS integer), 'masks', CAST(:n_masks AS integer)))
  ) AS a(n, action, entity, entity_id, data)
  ORDER BY a.n
), drf AS (
  DELETE FROM drafts WHERE sample_id = :sample_id AND kind = '{LeaseKind.annotate.value}' AND EXISTS (SELECT 1 FROM sub)
)
SELECT (SELECT id FROM job) AS job_id, (SELECT id FROM sub) AS submission_id
""").bindparams(bindparam("now", type_=UTCDateTime()))


def write(conn: Connection, *, sample_id: int, user_id: int, client_id: str, from_state: str, time_spent_s: float,
          clicks: list[Any], n_masks: int, payload: dict[str, Any], now: datetime) -> tuple[int, int | None]:
    """(fit job id, submission id or None when `client_id` is taken); `clicks` are the request's Click models."""
    row = conn.execute(SUBMIT, {
        "sample_id": sample_id, "user_id": user_id, "client_id": client_id, "from_state": from_state,
        "time_spent_s": time_spent_s, "n_clicks": len(clicks), "n_masks": n_masks, "now": now,
        "payload": json.dumps(payload),
        "view_ids": [c.view_id for c in clicks], "keypoints": [c.keypoint for c in clicks],
        "xs": [c.x for c in clicks], "ys": [c.y for c in clicks],
        "visibilities": [Visibility(c.visibility).value for c in clicks],
        "from_proposals": [c.from_proposal for c in clicks]}).one()
    return row.job_id, row.submission_id
