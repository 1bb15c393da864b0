from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator

from fastapi import APIRouter, Query, Request
from fastapi.responses import StreamingResponse
from sqlalchemy import select
from starlette.concurrency import run_in_threadpool

from backend.api.deps import AdminUser, JobQueueDep, SessionDep, SettingsDep
from backend.models.enums import JobKind, JobState
from backend.models.jobs import Job
from backend.schemas.admin import JobPublic
from backend.schemas.base import Id
from backend.services.jobs import jobs

router = APIRouter(prefix="/admin/jobs", tags=["admin: jobs"])


@router.get("", response_model=list[JobPublic])
def list_jobs(session: SessionDep, _admin: AdminUser, state: JobState | None = None, kind: JobKind | None = None,
              limit: int = Query(default=100, ge=1, le=1000)) -> list[Job]:
    query = select(Job).order_by(Job.id.desc()).limit(limit)
    if state is not None:
        query = query.where(Job.state == state)
    if kind is not None:
        query = query.where(Job.kind == kind)
    return list(session.execute(query).scalars())


@router.get("/{job_id}", response_model=JobPublic)
def get_job(job_id: Id, session: SessionDep, _admin: AdminUser) -> Job:
    return jobs.get(session, job_id)


@router.post("/{job_id}/cancel", response_model=JobPublic)
def cancel_job(job_id: Id, session: SessionDep, queue: JobQueueDep, admin: AdminUser) -> Job:
    return jobs.cancel(session, queue, job_id, admin.id)


@router.get("/{job_id}/events", response_class=StreamingResponse,
            responses={200: {"content": {"text/event-stream": {}}}})
def job_events(job_id: Id, request: Request, session: SessionDep, settings: SettingsDep,
               _admin: AdminUser) -> StreamingResponse:
    """Server-sent events: one `progress` event per change, then `done` when the job is final."""
    jobs.get(session, job_id)  # 404 before the stream starts
    factory = request.app.state.read_session_factory  # polls must not hold SQLite's writer lock
    poll_s = settings.sse_poll_seconds

    def snapshot() -> dict:
        with factory() as s:
            return JobPublic.model_validate(jobs.get(s, job_id)).model_dump(mode="json")

    async def events() -> AsyncIterator[str]:
        last = None
        while True:
            state = await run_in_threadpool(snapshot)
            if state != last:
                yield f"event: progress\ndata: {json.dumps(state)}\n\n"
                last = state
            if JobState(state["state"]) in jobs.FINAL_STATES:
                yield f"event: done\ndata: {json.dumps(state)}\n\n"
                return
            if await request.is_disconnected():
                return
            await asyncio.sleep(poll_s)

    return StreamingResponse(events(), media_type="text/event-stream", headers={"Cache-Control": "no-cache"})
