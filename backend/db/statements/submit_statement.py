"""PostgreSQL: what a submission writes, in one statement; two variants.

`SUBMIT_ALONE` (the annotators' hot path): the whole submission in one round trip, run in autocommit (no
BEGIN, no COMMIT, no lock statement before it). Its first CTE is the gate: the sample moves to `fitting`,
its lease cleared, only if the caller's live lease, the sample's state, the client id and every click pass the
checks `services.labeling.submissions` makes in Python; every other write hangs on that row, so a failed check writes
nothing and the caller takes the checked path below to name the error (or to find the earlier submission
a retry repeats).

`SUBMIT`: everything a submission writes after the caller locked the sample and checked it (two round trips in
all). The submission row has `ON CONFLICT (client_id) DO NOTHING` (the unique constraint decides a concurrent
twin): when it is not written, the caller raises and the transaction, job row included, is rolled back.

Both: data-modifying CTEs writing the fit job row, the submission pointing at it, every click (one `unnest` of
arrays, so the text does not depend on the number of clicks and psycopg prepares it once: each text stays
under psycopg's 4 KiB query cache, a test), the sample's move to `fitting`, the four audit rows (job.create,
the two state changes, submission.create, in that order) and the deletion of the sample's annotation drafts.
SQLite runs the same writes as separate statements (services.labeling.submissions).
"""
from __future__ import annotations

import json
from datetime import datetime
from typing import Any

from sqlalchemy import Connection, bindparam, text

from backend.db.base import UTCDateTime
from backend.models.enums import JobKind, JobState, LeaseKind, SampleState, Visibility

# The writes after the submission row, shared by both statements: every click (one `unnest` of arrays), the
# four audit rows in order, the drafts' deletion; all gated on `sub` (and `job`) having a row.
_AFTER_SUBMISSION = f"""clk AS (
  INSERT INTO clicks (submission_id, sample_id, view_id, keypoint, x_px, y_px, visibility, from_proposal, user_id,
                      time_spent_s, created_at)
  SELECT sub.id, :sample_id, t.view_id, t.keypoint, t.x, t.y, t.visibility, t.from_proposal, :user_id,
         :time_spent_s, :now
  FROM sub, unnest(CAST(:view_ids AS integer[]), CAST(:keypoints AS integer[]), CAST(:xs AS double precision[]),
                   CAST(:ys AS double precision[]), CAST(:visibilities AS varchar[]),
                   CAST(:from_proposals AS boolean[])) AS t(view_id, keypoint, x, y, visibility, from_proposal)
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
SELECT (SELECT id FROM job) AS job_id, (SELECT id FROM sub) AS submission_id"""

_JOB_COLUMNS = """INSERT INTO jobs (kind, state, progress, message, sample_id, payload, created_by_id, created_at,
                    updated_at, dispatched_at, attempts)"""
_SUBMISSION_COLUMNS = """INSERT INTO submissions (fit_job_id, client_id, sample_id, user_id, time_spent_s, n_clicks,
                           n_masks, created_at)
  SELECT job.id, :client_id, :sample_id, :user_id, :time_spent_s, :n_clicks, :n_masks, :now FROM job"""

SUBMIT = text(f"""
WITH job AS (
  {_JOB_COLUMNS}
  VALUES ('{JobKind.fit.value}', '{JobState.queued.value}', 0.0, '', :sample_id, CAST(:payload AS json), :user_id,
          :now, :now, :now, 0)
  RETURNING id
), sub AS (
  {_SUBMISSION_COLUMNS}
  ON CONFLICT (client_id) DO NOTHING
  RETURNING id
), smp AS (
  UPDATE samples SET state = '{SampleState.fitting.value}', leased_by_id = NULL, lease_kind = NULL,
                     lease_token = NULL, lease_expires_at = NULL, updated_at = :now
  WHERE id = :sample_id AND EXISTS (SELECT 1 FROM sub)
), {_AFTER_SUBMISSION}
""").bindparams(bindparam("now", type_=UTCDateTime()))

# The whole submission, checks included, in one statement (run alone, in autocommit): `smp` moves the sample to
# `fitting` only if the caller holds its live annotate lease (the token, when given, matching), no submission
# has this client id yet, and every click lies on a view of the sample, inside its image (as
# annotation_input.check_clicks: the image spans [-0.5, W - 0.5] x [-0.5, H - 0.5]); every other write hangs on
# that row. A plain INSERT of the submission: a client id taken meanwhile by a concurrent request is a unique
# violation that aborts the whole statement (nothing written), where ON CONFLICT would have left the sample
# and job rows written and committed.
SUBMIT_ALONE = text(f"""
WITH smp AS (
  UPDATE samples SET state = '{SampleState.fitting.value}', leased_by_id = NULL, lease_kind = NULL,
                     lease_token = NULL, lease_expires_at = NULL, updated_at = :now
  WHERE id = :sample_id AND state = '{SampleState.needs_annotation.value}' AND leased_by_id = :user_id
    AND lease_kind = '{LeaseKind.annotate.value}' AND lease_expires_at > :now
    AND lease_token = coalesce(CAST(:lease_token AS varchar), lease_token)
    AND NOT EXISTS (SELECT FROM submissions WHERE client_id = :client_id)
    AND NOT EXISTS (SELECT FROM unnest(CAST(:view_ids AS integer[]), CAST(:xs AS double precision[]),
                                       CAST(:ys AS double precision[])) AS t(view_id, x, y)
                    LEFT JOIN views v ON v.id = t.view_id AND v.sample_id = :sample_id
                    WHERE v.id IS NULL OR t.x NOT BETWEEN -0.5 AND v.width - 0.5
                       OR t.y NOT BETWEEN -0.5 AND v.height - 0.5)
  RETURNING id
), job AS (
  {_JOB_COLUMNS}
  SELECT '{JobKind.fit.value}', '{JobState.queued.value}', 0.0, '', :sample_id, CAST(:payload AS json), :user_id,
         :now, :now, :now, 0 FROM smp
  RETURNING id
), sub AS (
  {_SUBMISSION_COLUMNS}
  RETURNING id
), {_AFTER_SUBMISSION}
""").bindparams(bindparam("now", type_=UTCDateTime()))


def _params(sample_id: int, user_id: int, client_id: str, time_spent_s: float, clicks: list[Any], n_masks: int,
            payload: dict[str, Any], now: datetime) -> dict[str, Any]:
    return {
        "sample_id": sample_id, "user_id": user_id, "client_id": client_id,
        "from_state": SampleState.needs_annotation.value, "time_spent_s": time_spent_s, "n_clicks": len(clicks),
        "n_masks": n_masks, "now": now, "payload": json.dumps(payload),
        "view_ids": [c.view_id for c in clicks], "keypoints": [c.keypoint for c in clicks],
        "xs": [c.x for c in clicks], "ys": [c.y for c in clicks],
        "visibilities": [Visibility(c.visibility).value for c in clicks],
        "from_proposals": [c.from_proposal for c in clicks]}


def write(conn: Connection, *, sample_id: int, user_id: int, client_id: str, from_state: str, time_spent_s: float,
          clicks: list[Any], n_masks: int, payload: dict[str, Any], now: datetime) -> tuple[int, int | None]:
    """(fit job id, submission id or None when `client_id` is taken); `clicks` are the request's Click models.
    For a caller that locked the sample and checked the lease, its state and the clicks itself."""
    params = _params(sample_id, user_id, client_id, time_spent_s, clicks, n_masks, payload, now)
    row = conn.execute(SUBMIT, {**params, "from_state": from_state}).one()
    return row.job_id, row.submission_id


def write_alone(conn: Connection, *, sample_id: int, user_id: int, client_id: str, lease_token: str | None,
                time_spent_s: float, clicks: list[Any], payload: dict[str, Any],
                now: datetime) -> tuple[int, int] | None:
    """SUBMIT_ALONE on `conn` (in autocommit: the statement is the transaction): (fit job id, submission id),
    or None when a check failed and nothing was written (the caller finds out which through the checked path).
    A client id taken by a concurrent request raises IntegrityError, with nothing written either."""
    params = _params(sample_id, user_id, client_id, time_spent_s, clicks, 0, payload, now)
    row = conn.execute(SUBMIT_ALONE, {**params, "lease_token": lease_token}).one()
    return None if row.submission_id is None else (row.job_id, row.submission_id)
