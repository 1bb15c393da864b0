"""Agreement (issue 40, services.review.agreement): a picked sample is annotated again, blind, by another annotator;
the 2D and 3D disagreement per keypoint, per person and overall; the better-supported fit becomes the label."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import text

from backend.models.enums import Role
from backend.services.review.agreement import disagreement_2d, disagreement_3d_mm, picked
from backend.services.review.label_audits import QualityConfig

BASE_KEYPOINTS_M = np.linspace(0, 0.1, 63).reshape(21, 3)


def _share(env, share: float) -> None:
    response = env.client.put("/api/admin/quality/settings", json={"agreement_share": share},
                              headers=env.headers(Role.admin))
    assert response.status_code == 200, response.text
    assert response.json()["agreement_share"] == share


def _submit(env, h, role: Role, shift_px: float = 0.0) -> tuple[dict, int]:
    """`role` takes the next annotate task and submits every keypoint in every view at (10 + k + shift, 20)."""
    task = h.next_task(env, role)
    body = h.body(task)
    for click in body["clicks"]:
        click["x"] += shift_px
    response = env.client.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=body,
                               headers=env.headers(role))
    assert response.status_code == 201, response.text
    return task, response.json()["id"]


def _fit(env, sample_id: int, submission_id: int, *, offset_mm: float, residual_px: float) -> int:
    """Record (as the worker would) the fit of one submission: the keypoints moved by `offset_mm` along x."""
    from backend.services.captures.samples import views_of
    from backend.services.review.verification import HeuristicThresholds
    from workers.tasks import records

    keypoints = BASE_KEYPOINTS_M + np.array([offset_mm / 1000.0, 0.0, 0.0])
    with env.session() as session, session.begin():
        views = views_of(session, sample_id, with_masks=False)
        return records.record_fit(
            session, sample_id, params=[0.0] * 61, keypoints_m=keypoints.tolist(),
            view_ious={v.id: 0.9 for v in views}, diagnostics={"mean_residual_2d_px": residual_px},
            inputs={"submission_ids": [submission_id]}, model_file="builtin", thresholds=HeuristicThresholds()).id


def _state(env, sample_id: int) -> tuple[str, int | None]:
    with env.session() as s:
        return tuple(s.execute(text("SELECT state, current_fit_id FROM samples WHERE id = :i"), {"i": sample_id}).one())


def _second_annotator(env) -> int:
    """Another active annotator: a sample is held for a second look only while someone else may take it."""
    response = env.client.post("/api/admin/users", json={"email": "second@example.org", "password": "a long password 2",
                                                         "role": "annotator"}, headers=env.headers(Role.admin))
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _agreement(env) -> dict:
    response = env.client.get("/api/admin/quality", headers=env.headers(Role.admin))
    assert response.status_code == 200, response.text
    return response.json()["agreement"]


def test_a_picked_sample_goes_blind_to_another_annotator_and_its_disagreement_is_measured(env, h):
    _share(env, 1.0)
    _second_annotator(env)
    (sample_id,) = h.seed(env, frames=1, cameras=2, state="needs_annotation")
    task, first_submission = _submit(env, h, Role.annotator)
    assert task["sample_id"] == sample_id
    first_fit = _fit(env, sample_id, first_submission, offset_mm=0.0, residual_px=2.0)
    # Picked: back in the annotate queue, with the first look's fit cleared (no proposal from it).
    assert _state(env, sample_id) == ("needs_annotation", None)
    assert _agreement(env)["waiting"] == 1
    # Never the same person: the first annotator is not given it again.
    assert env.client.post("/api/annotate/next", headers=env.headers(Role.annotator)).status_code == 204
    second_task = h.next_task(env, Role.admin)
    assert second_task["sample_id"] == sample_id and second_task["state"] == "needs_annotation"
    # Blind: no draft carried, no previous clicks, no proposal from the first look's fit.
    draft = env.client.get(f"/api/annotate/samples/{sample_id}/draft", headers=env.headers(Role.admin))
    assert draft.status_code == 204
    proposals = env.client.get(f"/api/annotate/samples/{sample_id}/proposals", headers=env.headers(Role.admin))
    assert proposals.status_code == 200, proposals.text
    assert proposals.json()["previous_clicks"] == []
    assert all(source["kind"] != "fit" for source in proposals.json()["sources"])
    body = h.body(second_task)
    for click in body["clicks"]:
        click["x"] += 3.0  # the second person's points 3 px to the right of the first's
    response = env.client.post(f"/api/annotate/samples/{sample_id}/submissions", json=body,
                               headers=env.headers(Role.admin))
    assert response.status_code == 201, response.text
    second_fit = _fit(env, sample_id, response.json()["id"], offset_mm=4.0, residual_px=1.0)
    # The label: the better-supported fit (lower residual), reviewed as usual.
    assert _state(env, sample_id) == ("in_review", second_fit)
    figures = _agreement(env)
    assert (figures["pairs"], figures["waiting"], figures["disputed"]) == (1, 0, 0)
    assert figures["mean_px"] == pytest.approx(3.0) and figures["mean_mm"] == pytest.approx(4.0)
    # Every (pair, keypoint) cell is 3 px: the mean is 3, and its interval has no width.
    assert figures["keypoint_px_mean"] == pytest.approx(3.0) and figures["keypoint_px_ci95"] == pytest.approx([3, 3])
    clicked = set(task["keypoints_to_click"])
    assert all(figures["per_keypoint_px"][k] == pytest.approx(3.0) for k in clicked)
    assert all(figures["per_keypoint_px"][k] is None for k in set(range(21)) - clicked)
    assert [p["pairs"] for p in figures["people"]] == [1, 1]
    assert all(p["mean_px"] == pytest.approx(3.0) and p["mean_mm"] == pytest.approx(4.0) for p in figures["people"])
    with env.session() as s:
        pair = s.execute(text("SELECT first_fit_id, second_fit_id, label_fit_id FROM agreement_pairs")).one()
    assert tuple(pair) == (first_fit, second_fit, second_fit)


def test_fits_further_apart_than_the_threshold_are_disputed_and_the_lower_residual_is_the_label(env, h):
    _share(env, 1.0)
    _second_annotator(env)
    (sample_id,) = h.seed(env, frames=1, cameras=1, state="needs_annotation")
    _, first_submission = _submit(env, h, Role.annotator)
    first_fit = _fit(env, sample_id, first_submission, offset_mm=0.0, residual_px=1.5)
    _, second_submission = _submit(env, h, Role.reviewer)
    _fit(env, sample_id, second_submission, offset_mm=20.0, residual_px=4.0)
    assert _state(env, sample_id) == ("in_review", first_fit)  # disputed: the review is the third look
    figures = _agreement(env)
    assert figures["disputed"] == 1 and figures["mean_mm"] == pytest.approx(20.0)
    assert figures["mean_px"] == pytest.approx(0.0)


def test_at_share_zero_no_sample_is_annotated_twice(env, h):
    _share(env, 0.0)
    (sample_id,) = h.seed(env, frames=1, cameras=1, state="needs_annotation")
    _, submission = _submit(env, h, Role.annotator)
    fit = _fit(env, sample_id, submission, offset_mm=0.0, residual_px=1.0)
    assert _state(env, sample_id) == ("in_review", fit)
    assert h.count(env, "agreement_pairs") == 0
    assert _agreement(env)["pairs"] == 0


def test_picking_takes_the_share_and_repeats_with_the_seed():
    config = QualityConfig(agreement_share=0.2, audit_seed=7)
    chosen = [i for i in range(1, 5001) if picked(config, i)]
    assert 0.18 < len(chosen) / 5000 < 0.22
    assert chosen == [i for i in range(1, 5001) if picked(QualityConfig(agreement_share=0.2, audit_seed=7), i)]
    assert chosen != [i for i in range(1, 5001) if picked(QualityConfig(agreement_share=0.2, audit_seed=8), i)]
    assert not any(picked(QualityConfig(agreement_share=0.0), i) for i in range(1, 1001))


def test_disagreement_figures_on_constructed_points():
    first = {(1, 0): (10.0, 20.0), (2, 0): (50.0, 50.0), (1, 4): (0.0, 0.0), (2, 8): (5.0, 5.0)}
    second = {(1, 0): (13.0, 24.0), (2, 0): (50.0, 49.0), (1, 4): (3.0, 0.0), (1, 8): (5.0, 5.0)}
    per = disagreement_2d(first, second)
    assert per[0] == pytest.approx(3.0)  # (5 px + 1 px) / 2 views
    assert per[4] == pytest.approx(3.0)
    assert per[8] is None  # placed in different views only
    assert sum(d is not None for d in per) == 2
    moved = BASE_KEYPOINTS_M + np.array([0.0, 0.003, 0.004])
    assert disagreement_3d_mm(BASE_KEYPOINTS_M, moved) == pytest.approx(5.0)


@pytest.mark.parametrize("share", [1.5, -0.1])
def test_an_out_of_range_share_is_refused_naming_the_field(env, share):
    response = env.client.put("/api/admin/quality/settings", json={"agreement_share": share},
                              headers=env.headers(Role.admin))
    assert response.status_code == 422 and "agreement_share" in response.text


def test_with_no_other_annotator_a_picked_sample_is_not_held_and_goes_to_review(env, h):
    # The team's only annotator (the reviewer and admin may annotate, but are not the team's annotators).
    _share(env, 1.0)
    (sample_id,) = h.seed(env, frames=1, cameras=1, state="needs_annotation")
    _, submission = _submit(env, h, Role.annotator)
    fit = _fit(env, sample_id, submission, offset_mm=0.0, residual_px=1.0)
    assert _state(env, sample_id) == ("in_review", fit)  # an ordinary annotated sample, their fit the label
    figures = _agreement(env)
    assert (figures["pairs"], figures["waiting"], figures["single"]) == (0, 0, 1)  # picked, not annotated twice
    with env.session() as s:
        assert s.execute(text("SELECT count(*) FROM annotation_flags")).scalar_one() == 0  # nothing keeps it from them


def test_a_sample_waiting_for_a_second_look_is_released_when_no_other_annotator_is_left(env, h):
    _share(env, 1.0)
    second = _second_annotator(env)
    (sample_id,) = h.seed(env, frames=1, cameras=1, state="needs_annotation")
    _, submission = _submit(env, h, Role.annotator)
    first_fit = _fit(env, sample_id, submission, offset_mm=0.0, residual_px=1.0)
    assert _state(env, sample_id) == ("needs_annotation", None) and _agreement(env)["waiting"] == 1
    gone = env.client.patch(f"/api/admin/users/{second}", json={"is_active": False}, headers=env.headers(Role.admin))
    assert gone.status_code == 200, gone.text
    # Nothing the first annotator did is lost: their fit is the label, on its way to review.
    assert _state(env, sample_id) == ("in_review", first_fit)
    figures = _agreement(env)
    assert (figures["pairs"], figures["waiting"], figures["single"]) == (0, 0, 1)
    task = h.next_task(env, Role.reviewer, "review")
    assert task["sample_id"] == sample_id and task["fit"]["id"] == first_fit


def test_the_interval_of_the_disagreement_is_normal_over_the_cells_and_absent_under_two():
    from backend.services.review.agreement import _interval

    assert _interval([]) is None and _interval([2.0]) is None
    low, high = _interval([1.0, 2.0, 3.0, 4.0])
    half = 1.96 * (5 / 3) ** 0.5 / 2  # sd of 1..4 is sqrt(5/3); n = 4
    assert (low, high) == pytest.approx((2.5 - half, 2.5 + half), abs=1e-4)


def test_the_simulation_judges_the_agreement_against_the_click_noise_only_without_swaps():
    from types import SimpleNamespace

    from backend.simulation.annotator import AnnotatorConfig
    from backend.simulation.bootstrap import BootstrapConfig, BootstrapSimulation

    def judged(swap: float, ci: list[float] | None) -> dict:
        sim = SimpleNamespace(config=BootstrapConfig(annotator=AnnotatorConfig(click_sigma_px=2.0,
                                                                                swap_probability=swap)))
        figures = {"pairs": 12, "single": 0, "waiting": 0, "keypoint_px_mean": 3.6, "keypoint_px_ci95": ci}
        return BootstrapSimulation._agreement_against_given(sim, figures)

    given = 2.0 * 3.141592653589793 ** 0.5  # 3.545 px
    assert judged(0.0, [3.3, 3.9])["given_px_mean"] == pytest.approx(given)
    assert judged(0.0, [3.3, 3.9])["ci_holds_given"] is True
    assert judged(0.0, [3.6, 3.9])["ci_holds_given"] is False
    assert judged(0.05, [3.3, 3.9])["ci_holds_given"] is None  # swaps: shown, not judged
    assert judged(0.0, None)["ci_holds_given"] is None
