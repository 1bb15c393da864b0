"""The round job's heuristic step: its summary split by sequence kind (green-screen vs cluttered), and the late
heuristic recording its IoU reference as record_fit does."""

from __future__ import annotations

from sqlalchemy import select, update

from backend.models.capture import Sample
from backend.models.enums import Role
from backend.models.fits import Fit
from backend.models.jobs import Job


def test_the_late_heuristic_records_its_iou_reference_and_the_summary_splits_by_sequence_kind(env, h):
    from workers.tasks.context import build_context
    from workers.tasks.round_steps import run_heuristic

    ids = h.seed(env, frames=5, cameras=1, state="fitting")
    # Two green-screen samples the heuristic accepts; two cluttered ones whose IoU fails it, and one without
    # view IoUs, which it cannot evaluate.
    for sample_id in ids[:2]:
        h.record_fit(env, sample_id, prediction={"confidences": [0.95] * 21})
    for sample_id in ids[2:]:
        h.record_fit(env, sample_id, prediction={"confidences": [0.95] * 21}, ious=0.3)
    launched = env.client.post("/api/admin/rounds", headers=env.headers(Role.admin), json={})
    assert launched.status_code == 201, launched.text
    with env.session() as session, session.begin():
        session.execute(update(Sample).where(Sample.id.in_(ids[2:])).values(green_screen=False))
        fits = session.execute(select(Fit).where(Fit.sample_id.in_(ids)).order_by(Fit.sample_id)).scalars().all()
        job_round = session.get(Job, launched.json()["job_id"]).round_id
        for fit in fits:
            fit.round_id = job_round  # as if the round's own predictions had been fitted
        late = fits[3]  # a fit the heuristic did not see when recorded: run_heuristic evaluates it
        late.heuristic = None
        late.inputs = {**(late.inputs or {}), "iou_reference": {"1": "chroma_key_cut"}}
        late_id = late.id
        fits[4].heuristic, fits[4].view_ious = None, {}
    ctx = build_context(env.settings, job_queue=env.queue)
    try:
        summary = run_heuristic(ctx, launched.json()["job_id"])
    finally:
        ctx.session_factory.kw["bind"].dispose()
    assert (summary["fits"], summary["evaluated"], summary["accepted"]) == (5, 4, 2)
    green, cluttered = summary["by_kind"]["green_screen"], summary["by_kind"]["cluttered"]
    assert (green["fits"], green["evaluated"], green["accepted"], green["failures"]) == (2, 2, 2, {})
    assert (cluttered["fits"], cluttered["evaluated"], cluttered["accepted"]) == (3, 2, 0)
    assert cluttered["failures"]["mean IoU"] == 2
    with env.session() as session:
        record = session.get(Fit, late_id).heuristic
    assert record["late"] is True and record["iou_reference"] == "chroma_key_cut"
    job = env.client.get(f"/api/admin/jobs/{launched.json()['job_id']}", headers=env.headers(Role.admin)).json()
    assert job["result"]["heuristic"]["by_kind"] == summary["by_kind"]
