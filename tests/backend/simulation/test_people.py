"""Simulated annotators and reviewers against the real API (the backend's app fixture, SQLite): what they
click and submit, how they decide, and that their time is counted with the unit costs.

The in-process app hands jobs to an in-memory queue, so the tests play the worker: they record fits made
from each sample's ground truth, moved by a known translation (its mean vertex error is that distance).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import text

from backend.models.enums import Role
from backend.services.captures.samples import views_of
from backend.services.review.verification import HeuristicThresholds
from backend.simulation.annotator import AnnotatorConfig, SimulatedAnnotator, iou, noisy_mask
from backend.simulation.client import ApiClient, ApiError
from backend.simulation.costs import HumanLedger, UnitCosts
from backend.simulation.reviewer import ReviewerConfig, SimulatedReviewer
from backend.simulation.team import Team
from backend.simulation.truth import GroundTruthIndex
from workers.capture import read_capture
from workers.tasks import records


@pytest.fixture(scope="module")
def capture_dir(tmp_path_factory) -> Path:
    from workers.synth.generator import generate_capture
    from workers.synth.plan import SynthConfig

    out = tmp_path_factory.mktemp("sim-capture") / "cap"
    generate_capture(out, SynthConfig(num_sequences=1, frames_per_sequence=3, seed=11, width_px=128), workers=1)
    return out


@pytest.fixture
def world(sqlite_env, capture_dir):
    """The app with the capture imported (all samples queued for annotation) and a ground-truth index."""
    env = sqlite_env
    admin = ApiClient(env.client, token_of(env, Role.admin))
    admin.import_capture(str(capture_dir), "sim", queue_for_annotation=True)
    truth = GroundTruthIndex({"sim": read_capture(capture_dir)}, admin.sample_index()["samples"])
    return env, admin, truth


def token_of(env, role: Role) -> str:
    return env.headers(role)["Authorization"].split()[1]


def record_true_fits(env, truth: GroundTruthIndex, offset_m: float | dict[int, float], done: set[int]) -> list[int]:
    """Play the worker: fit every queued fit job's sample with its ground truth moved by `offset_m` along x."""
    fitted = []
    for job_id, kind in list(env.queue.enqueued):
        if kind != "fit" or job_id in done:
            continue
        done.add(job_id)
        with env.session() as s, s.begin():
            sample_id = s.execute(text("SELECT sample_id FROM jobs WHERE id = :j"), {"j": job_id}).scalar_one()
            gt = truth.truth(sample_id)
            shift = offset_m[sample_id] if isinstance(offset_m, dict) else offset_m
            move = np.array([shift, 0.0, 0.0])
            params = np.concatenate([gt.betas, gt.pose, gt.global_orient, gt.transl + move])
            records.record_fit(s, sample_id, params=params, keypoints_m=gt.keypoints_3d + move,
                               view_ious={v.id: 0.9 for v in views_of(s, sample_id, with_masks=False)},
                               diagnostics={}, inputs={"submission_ids": [1]}, model_file="handloop-builtin v1",
                               thresholds=HeuristicThresholds(), job_id=job_id)
        fitted.append(sample_id)
    return fitted


def test_annotator_clicks_the_truth_with_noise_skips_hidden_points_and_corrects_masks(world):
    env, _, truth = world
    ledger = HumanLedger()
    config = AnnotatorConfig(click_sigma_px=2.0, swap_probability=0.0, mask_iou_threshold=1.0,
                             max_mask_corrections=2, boundary_noise_px=1.5, seed=1)
    annotator = SimulatedAnnotator("ann", ApiClient(env.client, token_of(env, Role.annotator)), truth, ledger, config)
    outcome = annotator.annotate_next(round_index=0)
    gt = truth.truth(outcome.sample_id)
    with env.session() as s:
        clicks = s.execute(text("SELECT c.keypoint, c.x_px, c.y_px, c.visibility, cc.name, v.width, v.height "
                                "FROM clicks c JOIN views v ON v.id = c.view_id "
                                "JOIN camera_calibrations cc ON cc.id = v.camera_id WHERE c.sample_id = :s"),
                           {"s": outcome.sample_id}).all()
        spent = s.execute(text("SELECT time_spent_s FROM submissions")).scalar_one()
        masks = s.execute(text("SELECT m.storage_key, cc.name FROM masks m JOIN views v ON v.id = m.view_id "
                               "JOIN camera_calibrations cc ON cc.id = v.camera_id WHERE m.kind = 'corrected'")).all()
    cams = list(gt.camera_names)
    residuals = []
    for keypoint, x, y, visibility, camera, width, height in clicks:
        c = cams.index(camera)
        u, v = gt.keypoints_2d[c, keypoint]
        inside = -0.5 <= u <= width - 0.5 and -0.5 <= v <= height - 0.5
        if gt.visibility[c, keypoint] and inside:
            assert visibility == "visible"
            residuals.append([x - u, y - v])
        else:
            assert visibility == "not_annotated" and x is None
    residuals = np.asarray(residuals)
    assert len(clicks) == 6 * len(cams) and len(residuals) == outcome.clicks > 10
    assert outcome.skipped_points == len(clicks) - outcome.clicks
    assert 1.0 < residuals.std() < 3.0 and np.abs(residuals.mean()) < 1.5  # sigma 2 px per coordinate
    # Time: 2 s per click, 12 s per corrected mask, sent with the submission and in the ledger.
    assert outcome.mask_corrections == len(masks) == 2
    assert spent == pytest.approx(outcome.clicks * 2 + 2 * 12) == pytest.approx(outcome.seconds)
    assert ledger.hours(0) == pytest.approx(outcome.seconds / 3600)
    storage = env.client.app.state.storage
    from backend.services.captures.masks import decode_png

    for key, camera in masks:
        corrected = decode_png(storage.get_bytes(key))
        assert 0.6 < iou(corrected, gt.hand_masks[camera]) < 1.0  # the true hand, with a noisy boundary


def test_annotator_swaps_two_fingertips_when_told_to(world):
    env, _, truth = world
    config = AnnotatorConfig(click_sigma_px=0.0, swap_probability=1.0, max_mask_corrections=0)
    annotator = SimulatedAnnotator("ann", ApiClient(env.client, token_of(env, Role.annotator)), truth,
                                   HumanLedger(), config)
    outcome = annotator.annotate_next(round_index=0)
    gt = truth.truth(outcome.sample_id)
    with env.session() as s:
        rows = s.execute(text("SELECT cc.name, c.keypoint, c.x_px, c.y_px FROM clicks c "
                              "JOIN views v ON v.id = c.view_id JOIN camera_calibrations cc ON cc.id = v.camera_id "
                              "WHERE c.x_px IS NOT NULL")).all()
    by_view: dict[str, dict[int, tuple[float, float]]] = {}
    for camera, keypoint, x, y in rows:
        by_view.setdefault(camera, {})[keypoint] = (x, y)
    views_with_swaps = 0
    for camera, points in by_view.items():
        c = list(gt.camera_names).index(camera)
        wrong = [k for k, xy in points.items() if not np.allclose(xy, gt.keypoints_2d[c, k], atol=1e-6)]
        tips = [k for k in (4, 8, 12, 16, 20) if k in points]
        if len(tips) >= 2:
            a, b = wrong  # exactly two fingertips, each at the other's place
            assert np.allclose(points[a], gt.keypoints_2d[c, b]) and np.allclose(points[b], gt.keypoints_2d[c, a])
            views_with_swaps += 1
        else:
            assert not wrong
    assert views_with_swaps == outcome.swapped_views > 0


def test_reviewer_judges_by_true_vertex_error_with_mistakes_and_costs(world):
    env, _, truth = world
    annotator = SimulatedAnnotator("ann", ApiClient(env.client, token_of(env, Role.annotator)), truth,
                                   HumanLedger(), AnnotatorConfig(max_mask_corrections=0))
    for _ in range(3):
        annotator.annotate_next(round_index=0)
    done: set[int] = set()
    record_true_fits(env, truth, 0.004, done)  # every fit 4 mm off
    ledger = HumanLedger(costs=UnitCosts(verification_s=5.0))
    reviewer_client = ApiClient(env.client, token_of(env, Role.reviewer))

    strict = SimulatedReviewer("strict", reviewer_client, truth, ledger, ReviewerConfig(accept_below_mm=3.0,
                                                                                        error_rate=0.0))
    first = strict.review_next(0, annotation_attempts={})
    assert first.decision == "annotate" and first.vertex_mm == pytest.approx(4.0, abs=1e-6) and not first.mistake
    second = strict.review_next(0, annotation_attempts={s: 2 for s in truth.sample_ids})
    assert second.decision == "reject"
    lenient_but_wrong = SimulatedReviewer("flip", reviewer_client, truth, ledger,
                                          ReviewerConfig(accept_below_mm=10.0, error_rate=1.0))
    third = lenient_but_wrong.review_next(0, annotation_attempts={})
    assert third.decision == "annotate" and third.mistake  # a good fit, wrongly sent back
    assert strict.review_next(0, {}) is None
    effort = ledger.effort(0)
    assert (effort.verifications, effort.rejects, effort.sent_to_annotation, effort.reviewer_mistakes) == (3, 1, 2, 1)
    assert ledger.hours(0) == pytest.approx(3 * 5 / 3600)
    with env.session() as s:
        states = dict(s.execute(text("SELECT id, state FROM samples")).all())
    assert sorted(states.values()) == ["needs_annotation", "needs_annotation", "rejected"]


def _bad_fits_in_review(env, truth, ids) -> None:
    """Fits from predictions (no clicks), 20 mm off (the heuristic has none), in review (the queue policy would space
    them out)."""
    with env.session() as s, s.begin():
        for sample_id in ids:
            s.execute(text("UPDATE samples SET state = 'fitting' WHERE id = :id"), {"id": sample_id})
            gt = truth.truth(sample_id)
            move = np.array([0.02, 0.0, 0.0])
            records.record_fit(s, sample_id, params=np.concatenate([gt.betas, gt.pose, gt.global_orient,
                                                                    gt.transl + move]),
                               keypoints_m=gt.keypoints_3d + move,
                               view_ious={v.id: 0.9 for v in views_of(s, sample_id, with_masks=False)},
                               diagnostics={}, inputs={}, model_file="handloop-builtin v1",
                               thresholds=HeuristicThresholds())
    with env.session() as s, s.begin():
        for sample_id in ids:
            s.execute(text("UPDATE samples SET state = 'in_review' WHERE id = :id AND state = 'fitted'"),
                      {"id": sample_id})


def test_reviewer_discards_bad_fits_from_predictions_up_to_the_limit_then_sends_them_to_annotation(world):
    env, _, truth = world
    ids = truth.sample_ids[:3]
    _bad_fits_in_review(env, truth, ids)
    ledger = HumanLedger()
    reviewer = SimulatedReviewer("rev", ApiClient(env.client, token_of(env, Role.reviewer)), truth, ledger,
                                 ReviewerConfig(error_rate=0.0, discards_before_annotation=1))
    in_round_0 = reviewer.review_next(0, annotation_attempts={}, discards={})
    assert in_round_0.decision == "annotate"  # D_0 is all round 1 trains on: round 0 never discards
    discarded_once = reviewer.review_next(1, annotation_attempts={}, discards={})
    assert discarded_once.decision == "discard" and discarded_once.vertex_mm > 8.0
    at_the_limit = reviewer.review_next(1, annotation_attempts={}, discards={s: 1 for s in ids})
    assert at_the_limit.decision == "annotate"
    assert reviewer.review_next(1, {}, {}) is None
    effort = ledger.effort(1)
    assert (effort.verifications, effort.discards, effort.sent_to_annotation) == (2, 1, 1)
    with env.session() as s:
        states = dict(s.execute(text("SELECT id, state FROM samples")).all())
    assert states == {in_round_0.sample_id: "needs_annotation", discarded_once.sample_id: "fitted",
                      at_the_limit.sample_id: "needs_annotation"}
    with pytest.raises(ValueError, match="discards_before_annotation"):
        ReviewerConfig(discards_before_annotation=-1)


def test_reviewer_discards_in_round_0_only_once_d0_holds_its_floor(world):
    env, _, truth = world
    ids = truth.sample_ids[:3]
    _bad_fits_in_review(env, truth, ids)
    ledger = HumanLedger()
    reviewer = SimulatedReviewer("rev", ApiClient(env.client, token_of(env, Role.reviewer)), truth, ledger,
                                 ReviewerConfig(error_rate=0.0, discards_before_annotation=1, round0_discard_floor=5))
    below = reviewer.review_next(0, {}, {}, labels_so_far=lambda: 4)
    assert below.decision == "annotate"  # D_0 short of its floor: the annotators make it up
    at_floor = reviewer.review_next(0, {}, {}, labels_so_far=lambda: 5)
    assert at_floor.decision == "discard"
    unknown = reviewer.review_next(0, {}, {})  # no count to compare: as without a floor
    assert unknown.decision == "annotate"
    assert ledger.effort(0).discards == 1
    with env.session() as s:
        assert s.execute(text("SELECT state FROM samples WHERE id = :id"),
                         {"id": at_floor.sample_id}).scalar_one() == "fitted"
    with pytest.raises(ValueError, match="round0_discard_floor"):
        ReviewerConfig(round0_discard_floor=-1)


@pytest.mark.parametrize(("round_index", "discards_so_far", "labels", "expected"), [
    (1, 0, None, True), (1, 1, None, False),  # rounds >= 1: the per-sample limit only
    (0, 0, None, False), (0, 0, 29, False), (0, 0, 30, True), (0, 1, 30, False),  # round 0: the floor as well
])
def test_reviewer_discard_policy(round_index, discards_so_far, labels, expected):
    config = ReviewerConfig(discards_before_annotation=1, round0_discard_floor=30)
    asked = []

    def size() -> int:
        asked.append(labels)
        return labels

    assert config.may_discard(round_index, discards_so_far, None if labels is None else size) is expected
    assert len(asked) <= int(round_index == 0 and discards_so_far == 0)  # D_0's size asked only where it decides
    assert ReviewerConfig(discards_before_annotation=1).may_discard(0, 0, lambda: 10_000) is False  # no floor: never


def test_team_works_until_the_queues_are_empty_and_the_books_add_up(world):
    env, admin, truth = world
    ledger = HumanLedger()
    annotators = [SimulatedAnnotator(f"ann{i}", ApiClient(env.client, token_of(env, Role.annotator)), truth, ledger,
                                     AnnotatorConfig(max_mask_corrections=1, mask_iou_threshold=0.9, seed=i))
                  for i in range(1)]
    reviewers = [SimulatedReviewer("rev", ApiClient(env.client, token_of(env, Role.reviewer)), truth, ledger,
                                   ReviewerConfig(accept_below_mm=8.0, error_rate=0.0))]
    team = Team(annotators, reviewers)
    bad_first = set(truth.sample_ids[:1])
    done: set[int] = set()
    passes: list[int] = []

    def worker() -> None:  # the first fit of one sample is 20 mm off, every other fit 2 mm
        passes.append(1)
        offsets = {s: (0.02 if s in bad_first and len(passes) == 1 else 0.002) for s in truth.sample_ids}
        record_true_fits(env, truth, offsets, done)

    work = team.work_until_done(0, worker)
    stats = admin.statistics()
    assert stats["samples_by_state"] == {"accepted": 3}
    assert stats["rounds"][0]["added"] == {"heuristic": 0, "manual": 0, "annotated": 3}
    assert stats["rounds"][0]["dataset_size_after"] == 3
    assert [r.decision for r in work.reviews].count("annotate") == 1 and len(work.annotations) == 4
    effort = ledger.effort(0)
    assert effort.submissions == 4 == stats["submissions"] and effort.verifications == 4
    with env.session() as s:
        clicked = s.execute(text("SELECT count(*) FROM clicks WHERE visibility != 'not_annotated'")).scalar_one()
        corrected = s.execute(text("SELECT count(*) FROM masks WHERE kind = 'corrected'")).scalar_one()
        spent = s.execute(text("SELECT sum(time_spent_s) FROM submissions")).scalar_one()
    assert effort.clicks == clicked and effort.mask_corrections == corrected
    assert ledger.hours(0) * 3600 == pytest.approx(spent + 4 * 5)
    with env.session() as s:  # the sample sent back was clicked again, all 21 keypoints this time
        rows = s.execute(text("SELECT sub.sample_id, count(*) FROM clicks c JOIN submissions sub "
                              "ON sub.id = c.submission_id GROUP BY sub.id ORDER BY sub.id")).all()
    views = len(truth.truth(truth.sample_ids[0]).camera_names)
    assert [n for sample, n in rows if sample in bad_first] == [6 * views, 21 * views]


def test_configs_and_client_refuse_bad_values(world):
    env, _, _ = world
    with pytest.raises(ValueError, match="click_sigma_px"):
        AnnotatorConfig(click_sigma_px=float("nan"))
    with pytest.raises(ValueError, match="error_rate"):
        ReviewerConfig(error_rate=1.5)
    with pytest.raises(ValueError, match="verification_s"):
        UnitCosts(verification_s=-1)
    with pytest.raises(ApiError) as refused:
        ApiClient(env.client, token_of(env, Role.annotator)).statistics()
    assert refused.value.status == 403
    rng = np.random.default_rng(0)
    square = np.zeros((40, 40), bool)
    square[10:30, 10:30] = True
    assert noisy_mask(square, 0.0, rng).sum() == square.sum()
    assert 0.7 < iou(noisy_mask(square, 2.0, rng), square) < 1.0


def test_the_offered_proposal_is_the_first_source_holding_a_confident_point_as_in_the_browser():
    """annotation.js offers, per view and keypoint, the first source's point, skipping a scored source's points
    under 0.3 (MVNet's and the detector's alike); the simulated annotator sees the same."""
    from backend.simulation.annotator import offered_proposals

    sources = {"sources": [
        {"kind": "fit", "confidences": None, "views": {"1": [[10.0, 10.0], None, [12.0, 12.0]]}},
        {"kind": "detector", "confidences": [0.9, 0.2, 0.9], "views": {"1": [[20.0, 20.0], [21.0, 21.0], [22.0, 22.0]],
                                                                        "2": [[30.0, 30.0], [31.0, 31.0], None]}},
        {"kind": "mvnet", "confidences": [0.9, 0.5, 0.1], "views": {"2": [[40.0, 40.0], [41.0, 41.0], [42.0, 42.0]]}},
    ]}
    assert offered_proposals(sources) == {
        (1, 0): (10.0, 10.0), (1, 2): (12.0, 12.0),  # the fit first where it has the point
        # (1, 1): the fit has none, the detector's is under 0.3 and MVNet has no view 1: nothing offered
        (2, 0): (30.0, 30.0),  # the detector before MVNet
        (2, 1): (41.0, 41.0),  # the detector's under 0.3: MVNet's
        # (2, 2): the detector has none, MVNet's is under 0.3
    }


def test_annotator_accepts_the_triangulation_of_its_own_clicks_after_two_hand_placed_views(world):
    """No fit or MVNet yet, so the page's only proposal is the point triangulated from the annotator's own
    clicks: offered once a keypoint was placed by hand in two views, accepted within 4 px of the truth; the
    accepted points never feed a triangulation (each ends where the hand-placed clicks alone put it)."""
    from backend.simulation.page_triangulation import project_point, triangulate_clicked

    env, _, truth = world
    client = ApiClient(env.client, token_of(env, Role.annotator))
    seen: dict[str, dict] = {}
    next_task, proposals = client.next_annotation, client.proposals
    client.next_annotation = lambda: seen.setdefault("task", next_task())
    client.proposals = lambda sample_id: seen.setdefault("proposals", proposals(sample_id))
    config = AnnotatorConfig(click_sigma_px=2.0, swap_probability=0.0, max_mask_corrections=0,
                             accept_proposals_within_px=4.0, seed=2)
    ledger = HumanLedger()
    outcome = SimulatedAnnotator("ann", client, truth, ledger, config).annotate_next(round_index=0)
    task, payload = seen["task"], seen["proposals"]
    assert outcome.sample_id == task["sample_id"] and not payload["sources"]  # nothing but triangulation
    cams = {c["view_id"]: c for c in payload["cameras"]}
    order = [v["id"] for v in task["views"]]  # the order the annotator worked in
    gt = truth.truth(task["sample_id"])
    names = list(gt.camera_names)
    with env.session() as s:
        rows = s.execute(text("SELECT view_id, keypoint, x_px, y_px, from_proposal FROM clicks "
                              "WHERE sample_id = :s AND x_px IS NOT NULL"), {"s": task["sample_id"]}).all()
    by_key: dict[int, list] = {}
    for view_id, k, x, y, from_proposal in sorted(rows, key=lambda r: order.index(r[0])):
        by_key.setdefault(k, []).append((view_id, (x, y), from_proposal))
    accepted = 0
    for k, placed in by_key.items():
        hand = [(cams[v], xy) for v, xy, from_proposal in placed if not from_proposal]
        for i, (view_id, xy, from_proposal) in enumerate(placed):
            if not from_proposal:
                continue
            accepted += 1
            assert sum(not p for _, _, p in placed[:i]) >= 2  # offered only after two hand-placed views
            # Where all of the keypoint's hand-placed clicks (and no accepted point) triangulate it.
            expected = project_point(triangulate_clicked(hand).point, cams[view_id])
            np.testing.assert_allclose(xy, expected, atol=1e-6)
            view = next(v for v in task["views"] if v["id"] == view_id)
            true_xy = gt.keypoints_2d[names.index(view["camera"]), k]
            assert np.hypot(*(np.asarray(xy) - true_xy)) < 6.0  # accepted within 4 px, then moved by later clicks
    views_with_accepted = len({v for p in by_key.values() for v, _, f in p if f})
    assert accepted == ledger.effort(0).accepted_proposals == ledger.effort(0).accepted_triangulated > 5
    assert outcome.clicks == len(rows) - accepted
    assert outcome.seconds == pytest.approx(outcome.clicks * 2 + views_with_accepted * 1)
