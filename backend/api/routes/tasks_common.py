"""Shared by the annotator and reviewer queues: how a leased sample is shown."""

from __future__ import annotations

from fastapi import Response
from pydantic import BaseModel
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.capture import Sequence
from backend.models.enums import SampleState
from backend.models.fits import Fit
from backend.schemas.tasks import TaskPublic, ViewPublic
from backend.services.captures.samples import get_sample, views_of
from backend.services.leases.queues import Lease
from workers.handmodel.keypoints import SPARSE_KEYPOINTS


def sequence_name_and_side(session: Session, sequence_id: int) -> tuple[str | None, str]:
    """The sequence's name in the capture and in exports ("seq000") and its hand ("right" or "left"): one
    primary-key lookup."""
    row = session.execute(select(Sequence.external_id, Sequence.side).where(Sequence.id == sequence_id)).first()
    return (None, "right") if row is None else (row[0], row[1])


def task_of(session: Session, lease: Lease, with_fit: bool = False) -> TaskPublic:
    """Built with `model_construct` from rows the database already typed: validating our own output again
    cost more than the queries on the annotators' hot path."""
    sample = lease.head or get_sample(session, lease.sample_id)  # head: returned by the lease statement
    shown = lease.views if lease.views is not None else views_of(session, sample.id)  # PostgreSQL's acquire: with it
    views = [
        ViewPublic.model_construct(id=v.id, camera=v.camera, width=v.width, height=v.height,
                                   image_url=f"/api/files/views/{v.id}/image",
                                   mask_url=f"/api/files/masks/{v.mask_id}" if v.mask_id is not None else None)
        for v in shown
    ]
    fit = None
    if with_fit and sample.current_fit_id is not None:
        row = session.get(Fit, sample.current_fit_id)
        if row is not None:
            # No heuristic verdict on a review task: a blind audit of a heuristic accept would show 'passed'
            # (services.review.label_audits, issue 40); the reviewer judges the fit, not the heuristic's word.
            # from_annotation: the fit used annotators' clicks, so it cannot be discarded (services.review.review).
            fit = {"id": row.id, "keypoints_m": row.keypoints_m, "params": row.params, "view_ious": row.view_ious,
                   "heuristic": None, "pose_distance": row.pose_distance, "model_file": row.model_file,
                   "from_annotation": row.from_annotation}
    if lease.views is not None:  # PostgreSQL's one-statement acquire returned them with the lease
        sequence, side = lease.sequence, lease.side or "right"
    else:
        sequence, side = sequence_name_and_side(session, sample.sequence_id)
    return TaskPublic.model_construct(
        sample_id=sample.id, state=SampleState(sample.state), lease_token=lease.token,
        lease_expires_at=lease.expires_at, sequence_id=sample.sequence_id,
        sequence=sequence, side=side, frame_index=sample.frame_index,
        time_s=sample.time_s, keypoints_to_click=list(SPARSE_KEYPOINTS), views=views, fit=fit)


def json_response(model: BaseModel, status_code: int = 200) -> Response:
    """The model's JSON as the response, serialised once by pydantic-core (FastAPI would validate a
    returned model against `response_model` again first; the route keeps `response_model` for OpenAPI)."""
    return Response(model.model_dump_json(), status_code=status_code, media_type="application/json")
