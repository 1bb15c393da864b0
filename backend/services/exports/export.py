"""The server's records of the dataset, for exports: accepted samples (D_i) with their fits, the index of
all samples, and MVNet's predictions. Plain reads; no torch here (the FreiHAND writer in workers/export
takes the records `export_records` builds)."""

from __future__ import annotations

from typing import Any

import numpy as np
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from backend.models.capture import CameraCalibration, Project, Sample, Sequence, View
from backend.models.enums import MaskKind
from backend.models.fits import Fit, Prediction
from backend.models.label_audit import GoldLabel
from backend.models.labels import Mask
from backend.models.review import Round, RoundMember
from backend.services.errors import InvalidInputError, NotFoundError
from workers.export.records import SampleRecord, ViewRecord

FOREGROUND_KINDS = (MaskKind.chroma_key.value, MaskKind.corrected.value)


def _members_query(up_to_round: int | None, project: str | None):
    query = (select(RoundMember, Round.index, Sample, Sequence.external_id, Fit, Project.name, Project.hand_model,
                    Sequence.side)
             .join(Round, Round.id == RoundMember.round_id)
             .join(Sample, Sample.id == RoundMember.sample_id)
             .join(Sequence, Sequence.id == Sample.sequence_id)
             .join(Project, Project.id == Sequence.project_id)
             .outerjoin(Fit, Fit.id == RoundMember.fit_id)
             .order_by(Round.index, RoundMember.id))
    if up_to_round is not None:
        query = query.where(Round.index <= up_to_round)
    if project is not None:
        query = query.where(Project.name == project)
    return query


def _check_project(session: Session, project: str | None) -> None:
    if project is not None and session.execute(select(Project.id).where(Project.name == project)).first() is None:
        raise NotFoundError(f"project {project!r} not found")


def fit_source(fit: Fit) -> str:
    """What a fit was made from (its inputs' source): "annotation", "prediction" or "detector"."""
    return str((fit.inputs or {}).get("source", "unknown"))


def _check_round(session: Session, up_to_round: int | None) -> None:
    """A round index beyond the last round names no round (404, as an unknown project), not everything."""
    if up_to_round is None:
        return
    last = session.scalar(select(func.max(Round.index)))
    if last is None or up_to_round > last:
        there = "no rounds yet" if last is None else f"the last round is D_{last}"
        raise NotFoundError(f"round D_{up_to_round} not found (up_to_round={up_to_round}): {there}")


def dataset(session: Session, up_to_round: int | None = None, project: str | None = None) -> dict[str, Any]:
    """The accepted samples (D_i up to a round index) with their fits, rounds and streams, as JSON values."""
    _check_project(session, project)
    _check_round(session, up_to_round)
    samples = [
        {"sample_id": sample.id, "sequence": seq, "sequence_id": sample.sequence_id, "frame_index": sample.frame_index,
         "split": sample.split, "side": side, "project": project_name, "round": index, "stream": member.stream,
         "fit": None if fit is None else {"id": fit.id, "params": fit.params, "keypoints_m": fit.keypoints_m,
                                          "model_file": fit.model_file, "prediction_id": fit.prediction_id,
                                          "heuristic": fit.heuristic, "source": fit_source(fit)}}
        for member, index, sample, seq, fit, project_name, _, side
        in session.execute(_members_query(up_to_round, project))
    ]
    hand_models = sorted({row[6] for row in session.execute(_members_query(up_to_round, project))} - {""})
    return {"count": len(samples), "hand_models": hand_models, "samples": samples}


def sample_index(session: Session, project: str | None = None) -> dict[str, Any]:
    """Every sample with its sequence's external id, frame, split and state: how a client maps the
    server's ids to a capture's frames (e.g. to compare with ground truth); `gold`: an admin marked its label gold
    (reviewers' decisions on it are their answers; it stays as it is)."""
    _check_project(session, project)
    query = (select(Sample.id, Sample.sequence_id, Sequence.external_id, Sample.frame_index, Sample.time_s,
                    Sample.split, Sample.state, Sample.current_fit_id, Sample.confidence, Project.name,
                    Sequence.side, GoldLabel.id.is_not(None))
             .join(Sequence, Sequence.id == Sample.sequence_id)
             .join(Project, Project.id == Sequence.project_id)
             .join(GoldLabel, GoldLabel.sample_id == Sample.id, isouter=True)
             .order_by(Sample.id))
    if project is not None:
        query = query.where(Project.name == project)
    keys = ("sample_id", "sequence_id", "sequence", "frame_index", "time_s", "split", "state", "current_fit_id",
            "confidence", "project", "side", "gold")
    samples = [dict(zip(keys, row, strict=True)) for row in session.execute(query)]
    return {"count": len(samples), "samples": samples}


def predictions(session: Session, round_index: int | None = None) -> dict[str, Any]:
    """MVNet's predictions (keypoints, confidences, model versions), optionally of one round only, each with the
    newest fit made from it ("fit": id, params (61,), the heuristic's record; None where none was made)."""
    newest = (select(Fit.prediction_id, func.max(Fit.id).label("fit_id")).where(Fit.prediction_id.is_not(None))
              .group_by(Fit.prediction_id).subquery())
    query = (select(Prediction, Round.index, Fit.id, Fit.params, Fit.heuristic)
             .outerjoin(Round, Round.id == Prediction.round_id)
             .outerjoin(newest, newest.c.prediction_id == Prediction.id)
             .outerjoin(Fit, Fit.id == newest.c.fit_id)
             .order_by(Prediction.id))
    if round_index is not None:
        query = query.where(Round.index == round_index)
    rows = [
        {"id": p.id, "sample_id": p.sample_id, "round": index, "mvnet_version": p.mvnet_version,
         "handsegnet_version": p.handsegnet_version, "keypoints_m": p.keypoints_m, "confidences": p.confidences,
         "mean_confidence": p.mean_confidence,
         "fit": None if fit_id is None else {"id": fit_id, "params": params, "heuristic": heuristic}}
        for p, index, fit_id, params, heuristic in session.execute(query)
    ]
    return {"count": len(rows), "predictions": rows}


def export_records(session: Session, up_to_round: int | None = None, project: str | None = None) -> list:
    """The accepted samples as `workers.export.records.SampleRecord`s (views in camera order, each with its
    newest foreground mask), for the FreiHAND writer. Samples accepted without a fit are refused."""

    _check_project(session, project)
    _check_round(session, up_to_round)
    records = []
    for member, index, sample, seq, fit, _, _, side in session.execute(_members_query(up_to_round, project)):
        if fit is None:
            raise InvalidInputError(f"sample {sample.id} was accepted without a fit; it cannot be exported")
        newest_foreground = (select(Mask.storage_key).where(Mask.view_id == View.id, Mask.kind.in_(FOREGROUND_KINDS))
                             .order_by(Mask.version.desc()).limit(1).correlate(View).scalar_subquery())
        views = [
            ViewRecord(name=cam.name, width=view.width, height=view.height, K=np.asarray(cam.K, np.float64),
                       dist=np.asarray(cam.dist, np.float64), R=np.asarray(cam.R, np.float64),
                       t=np.asarray(cam.t, np.float64), image_key=view.image_key, foreground_mask_key=mask_key)
            for view, cam, mask_key in session.execute(
                select(View, CameraCalibration, newest_foreground)
                .join(CameraCalibration, CameraCalibration.id == View.camera_id)
                .where(View.sample_id == sample.id).order_by(CameraCalibration.id))
        ]
        records.append(SampleRecord(
            sample_id=sample.id, fit_id=fit.id, sequence=seq, frame_index=sample.frame_index, split=sample.split,
            green_screen=sample.green_screen, round_index=index, stream=member.stream,
            params=np.asarray(fit.params, np.float64), keypoints_m=np.asarray(fit.keypoints_m, np.float64),
            model_file=fit.model_file, views=tuple(views), fit_source=fit_source(fit), side=side))
    return records
