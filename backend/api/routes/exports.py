from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Query
from sqlalchemy import select

from backend.api.deps import AdminUser, SessionDep
from backend.models.capture import Sample, Sequence
from backend.models.fits import Fit
from backend.models.review import Round, RoundMember

router = APIRouter(prefix="/admin/exports", tags=["admin: exports"])


@router.get("/dataset")
def export_dataset(session: SessionDep, _admin: AdminUser,
                   up_to_round: int | None = Query(default=None, ge=0, le=1_000_000)) -> dict[str, Any]:
    """The accepted samples (D_i up to a round index) with their fits and streams, as JSON. The
    FreiHAND-layout export is the export issue's; this is the server's record of it."""
    query = (select(RoundMember, Round.index, Sample, Sequence.external_id, Fit)
             .join(Round, Round.id == RoundMember.round_id)
             .join(Sample, Sample.id == RoundMember.sample_id)
             .join(Sequence, Sequence.id == Sample.sequence_id)
             .outerjoin(Fit, Fit.id == RoundMember.fit_id)
             .order_by(Round.index, RoundMember.id))
    if up_to_round is not None:
        query = query.where(Round.index <= up_to_round)
    samples = [
        {"sample_id": sample.id, "sequence": seq, "frame_index": sample.frame_index, "split": sample.split,
         "round": index, "stream": member.stream,
         "fit": None if fit is None else {"id": fit.id, "params": fit.params, "keypoints_m": fit.keypoints_m,
                                          "model_file": fit.model_file}}
        for member, index, sample, seq, fit in session.execute(query)
    ]
    return {"count": len(samples), "samples": samples}
