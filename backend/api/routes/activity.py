from __future__ import annotations

from fastapi import APIRouter, Response

from backend.api.deps import AnnotatorUser, SessionDep
from backend.api.routes.tasks_common import json_response
from backend.schemas.ui import ActivityCreate, ActivityPublic
from backend.services.statistics import activity

router = APIRouter(prefix="/activity", tags=["activity"])


@router.post("", response_model=ActivityPublic, status_code=201,
             responses={200: {"description": "This submission or decision was logged already."}})
def log_activity(body: ActivityCreate, session: SessionDep, user: AnnotatorUser) -> Response:
    """Time per action for one of your submissions or decisions (what the dashboard compares with the
    paper's 2 s per keypoint, 12 s per mask, 5 s per verification)."""
    event_id, duplicate = activity.record(session, user, body)
    public = ActivityPublic(id=event_id, duplicate=duplicate, summary=activity.summarise(body))
    return json_response(public, status_code=200 if duplicate else 201)
