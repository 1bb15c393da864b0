"""The cross-estimator heuristic (records.record_fit, `cross_heuristic`): in a later round, a fit from MVNet's
prediction that fails the paper's heuristic is accepted when it agrees with the detector's lift that the sample's
pre-annotation left, by the detector's heuristic thresholds."""

from __future__ import annotations

import json

import numpy as np
from sqlalchemy import text

from backend.models.enums import Role

LIFTED = np.linspace(0, 0.1, 63).reshape(21, 3).tolist()  # h.record_fit's fitted keypoints
UNSURE_MVNET = {"confidences": [0.7] * 21}  # under the paper's 0.8 mean: the paper's heuristic fails


def _preannotated(env, h, sample_id: int, detector_confidence: float = 0.7) -> int:
    """A sample whose pre-annotation fit the detector's heuristic did not take (IoU 0.3), back in 'fitting' as a
    later round's prediction would put it."""
    h.record_fit(env, sample_id, detection={"points_world": LIFTED, "confidence": [detector_confidence] * 21},
                 ious=0.3)
    h.set_state(env, [sample_id], "fitting")
    return sample_id


def _heuristic(env, fit_id: int) -> dict:
    with env.session() as s:
        value = s.execute(text("SELECT heuristic FROM fits WHERE id = :i"), {"i": fit_id}).scalar_one()
    return json.loads(value) if isinstance(value, str) else value  # SQLite hands JSON back as text


def _state(env, sample_id: int) -> str:
    with env.session() as s:
        return s.execute(text("SELECT state FROM samples WHERE id = :i"), {"i": sample_id}).scalar_one()


def test_a_fit_from_mvnet_that_agrees_with_the_detectors_lift_is_accepted_as_d_h(env, h):
    (sample_id,) = h.seed(env, frames=1, cameras=2, state="fitting")
    _preannotated(env, h, sample_id)
    assert _state(env, sample_id) == "fitting"
    fit_id = h.record_fit(env, sample_id, prediction=UNSURE_MVNET, offset_m=0.004)
    heuristic = _heuristic(env, fit_id)
    assert heuristic["accepted"] and heuristic["estimator"] == "mvnet+detector", heuristic
    assert any(r.startswith("mean confidence") for r in heuristic["failed"])  # the paper's verdict is kept
    assert heuristic["cross"]["accepted"]
    assert abs(heuristic["cross"]["mean_distance_m"] - 0.004 * np.sqrt(3)) < 1e-9  # the fit against the lift
    assert heuristic["mean_confidence"] == 0.7  # the top-level metrics stay MVNet's (the precision target's)
    assert _state(env, sample_id) == "accepted"
    with env.session() as s:
        reason, stream = s.execute(text(
            "SELECT d.reason, m.stream FROM decisions d JOIN round_members m ON m.fit_id = d.fit_id "
            "WHERE d.fit_id = :f AND d.by_heuristic"), {"f": fit_id}).one()
    assert reason == "heuristic (MVNet's fit against the detector's lift): all criteria met"
    assert stream == "heuristic"


def test_a_fit_far_from_the_lift_or_an_unsure_lift_waits_for_a_reviewer(env, h):
    far, unsure = h.seed(env, frames=2, cameras=2, state="fitting")
    _preannotated(env, h, far)
    far_fit = h.record_fit(env, far, prediction=UNSURE_MVNET, offset_m=0.02)  # 20 mm from every lifted point
    _preannotated(env, h, unsure, detector_confidence=0.4)
    unsure_fit = h.record_fit(env, unsure, prediction=UNSURE_MVNET)
    for sample_id, fit_id, criterion in ((far, far_fit, "mean 3D distance"), (unsure, unsure_fit, "mean confidence")):
        heuristic = _heuristic(env, fit_id)
        assert not heuristic["accepted"] and heuristic["estimator"] == "mvnet", heuristic
        assert any(r.startswith(criterion) for r in heuristic["cross"]["failed"]), heuristic["cross"]
        assert _state(env, sample_id) == "fitted"
    response = env.client.post("/api/review/next", headers=env.headers(Role.reviewer))
    assert response.status_code in (200, 204), response.text  # nothing accepted on their behalf


def test_without_a_pre_annotation_or_with_the_setting_off_only_the_papers_heuristic_judges(env, h):
    plain, off = h.seed(env, frames=2, cameras=2, state="fitting")
    plain_fit = h.record_fit(env, plain, prediction=UNSURE_MVNET)
    assert "cross" not in _heuristic(env, plain_fit) and _state(env, plain) == "fitted"
    env.settings.cross_heuristic = False
    try:
        _preannotated(env, h, off)
        off_fit = h.record_fit(env, off, prediction=UNSURE_MVNET)
    finally:
        env.settings.cross_heuristic = True
    assert "cross" not in _heuristic(env, off_fit) and _state(env, off) == "fitted"
