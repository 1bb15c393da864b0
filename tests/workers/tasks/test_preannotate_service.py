"""The pre-annotation job service without a broker, the detector replaced by a fake made from the ground
truth (tests/support/detector_fake.py): fits recorded from the detections, samples routed by the review
policy, progress reported; bad input refused with nothing written; a redelivered job records nothing twice;
the Celery task calls the service."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import func, select

from backend.models.capture import CameraCalibration, Project, Sample
from backend.models.enums import JobKind, JobState, SampleState
from backend.models.fits import Fit
from backend.models.jobs import Job
from backend.services.errors import ConflictError, InvalidInputError, NotFoundError, ServiceUnavailableError
from backend.services.jobs import jobs
from backend.services.jobs.jobs import InMemoryJobQueue
from backend.services.rounds import preannotation
from backend.services.transactions import run_after_commit
from backend.settings import Settings
from tests.support.detector_fake import FakeDetector
from tests.support.live_stack import TEST_SETTINGS, fresh_postgres, prepare_database, tiny_capture
from workers.fitting.config import DETECTOR_KP2D_WEIGHT
from workers.tasks import detection_inputs, preannotate
from workers.tasks.context import build_context

MISSING = "the hand landmark model file is missing: install it with scripts/fetch_models.sh"


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def database_url(request):
    """Both backends for the tests that ask for them (the others run on SQLite)."""
    if request.param == "sqlite":
        yield None
        return
    with fresh_postgres() as url:
        yield url


@pytest.fixture
def world(tmp_path, capture_cache, monkeypatch, request):
    capture = tiny_capture(capture_cache, frames=4)
    url = request.getfixturevalue("database_url") if "database_url" in request.fixturenames else None
    # No time gap between picked frames, and reviewers' capacity for 2 of the 4: the confidence ranking alone
    # decides who is reviewed. The detector's heuristic is off here (these tests are about the routing); the tests
    # that name it turn it on.
    settings = Settings(data_dir=tmp_path / "data", database_url=url, review_min_time_gap_s=0.0,
                        review_min_pose_distance=0.0, review_capacity_per_round=2, detector_heuristic=False,
                        **TEST_SETTINGS)
    project_id = prepare_database(settings, capture, queue_for_annotation=False)
    queue = InMemoryJobQueue()
    ctx = build_context(settings, job_queue=queue)
    fake = FakeDetector(capture)
    monkeypatch.setattr(preannotate, "detect", fake)
    monkeypatch.setattr(preannotation, "detector_problem", lambda: None)
    yield ctx, queue, project_id, fake
    ctx.session_factory.kw["bind"].dispose()


def _launch(ctx, queue, project_id, **options) -> int:
    """As the API does it: commit, then hand the job over."""
    with ctx.session_factory() as session:
        job_id = preannotation.launch(session, queue, project_id, actor_id=None, **options).id
        session.commit()
        run_after_commit(session)
    return job_id


def _counts(ctx):
    with ctx.session_factory() as session:
        fits = session.execute(select(func.count()).select_from(Fit)).scalar_one()
        jobs_ = session.execute(select(func.count()).select_from(Job)).scalar_one()
        states = dict(session.execute(select(Sample.state, func.count()).group_by(Sample.state)).all())
    return fits, jobs_, states


def test_preannotation_fits_every_sample_and_routes_them_by_the_review_policy(database_url, world, monkeypatch):
    ctx, queue, project_id, fake = world
    reported = []
    real_update = jobs.update_progress

    def spy(session, job_id, progress, message="", now=None):
        reported.append((job_id, progress, message))
        return real_update(session, job_id, progress, message, now)

    monkeypatch.setattr(jobs, "update_progress", spy)
    fake.outliers_by_frame = {0: 0, 1: 1, 2: 2, 3: 3}  # fewer agreeing views, lower confidence
    job_id = _launch(ctx, queue, project_id, rest="annotate")
    assert queue.enqueued == [(job_id, "preannotate")]
    result = preannotate.run_preannotation_job(ctx, job_id)
    assert result["samples"] == 4 and result["detected"] == 4 and result["fitted"] == 4, result
    assert fake.calls == 4
    with ctx.session_factory() as session:
        job = session.get(Job, job_id)
        assert job.state == JobState.succeeded and job.progress == 1.0
        fits = session.execute(select(Fit).order_by(Fit.id)).scalars().all()
        assert len(fits) == 4
        for fit in fits:
            assert fit.inputs["source"] == "detector" and fit.inputs["preannotate_job_id"] == job_id
            assert fit.inputs["residual_reweighted"] is True  # fitted again, reweighted by the first fit's residuals
            # The capture's chroma-key masks lead the fit; the detector's keypoints weigh little against them.
            assert fit.inputs["mask_ids"] and fit.diagnostics["weights"]["kp2d"] == DETECTOR_KP2D_WEIGHT
            assert fit.prediction_id is None and fit.heuristic is None  # the detector's heuristic is off here
            assert len(fit.inputs["detection"]["views"]) == 8 and fit.inputs["keypoints_2d"] > 8 * 21 // 2
        samples = session.execute(select(Sample).order_by(Sample.id)).scalars().all()
        for sample in samples:
            fit = session.get(Fit, sample.current_fit_id)
            assert sample.confidence == pytest.approx(fit.inputs["detection"]["frame_confidence"])
        states = {s.frame_index: s.state for s in samples}
        confidences = [s.confidence for s in samples]
    assert confidences == sorted(confidences, reverse=True) and len(set(confidences)) == 4, confidences
    # The reviewers' capacity (2) takes the most confident; the rest go to the annotators.
    assert states == {0: SampleState.in_review, 1: SampleState.in_review, 2: SampleState.needs_annotation,
                      3: SampleState.needs_annotation}
    assert result["to_review"] == 2 and result["fitted_to_annotators"] == 2
    own = [r for r in reported if r[0] == job_id]
    assert any("detecting hands" in m for _, _, m in own) and any("fitting" in m for _, _, m in own)
    assert [p for _, p, _ in own] == sorted(p for _, p, _ in own)  # the bar only moves forward


def test_detector_fits_are_close_to_the_truth(world):
    """The fit made from the (fake) detections with an outlier view lands on the hand: the detections are used."""
    from workers.capture import load_ground_truth, read_capture

    ctx, queue, project_id, fake = world
    preannotate.run_preannotation_job(ctx, _launch(ctx, queue, project_id))
    capture = read_capture(fake.capture_dir, check_images=False)
    truth = {f.index: load_ground_truth(f) for f in capture.sequences[0].frames}
    with ctx.session_factory() as session:
        rows = session.execute(select(Fit.keypoints_m, Sample.frame_index).join(Sample, Sample.id == Fit.sample_id)
                               ).all()
    errors_mm = [1000 * np.linalg.norm(np.asarray(kp) - truth[i].keypoints_3d, axis=1).mean() for kp, i in rows]
    assert max(errors_mm) < 15.0, errors_mm


def test_annotators_see_each_views_chroma_key_cut_at_the_detector_fits_wrist(world):
    """The page shows a view's newest mask: after pre-annotation that is the chroma key cut at the detector fit's
    wrist (kind "model"), nearer the true hand mask than hand and forearm; the fits still read the chroma key."""
    from backend.models.enums import MaskKind
    from backend.models.labels import Mask
    from backend.services.captures.samples import views_of
    from backend.simulation.annotator import iou
    from workers.capture import load_ground_truth, read_capture
    from workers.tasks.detector_masks import NEAR_SILHOUETTE_PX, mask_key, near, record_hand_masks
    from workers.tasks.inputs import read_mask

    ctx, queue, project_id, fake = world
    result = preannotate.run_preannotation_job(ctx, _launch(ctx, queue, project_id))
    assert result["hand_masks"] == 4 * 8, result
    capture = read_capture(fake.capture_dir, check_images=False)
    truth = {f.index: load_ground_truth(f) for f in capture.sequences[0].frames}
    cut_iou, chroma_iou = [], []
    with ctx.session_factory() as session:
        for sample in session.execute(select(Sample)).scalars():
            fit = session.get(Fit, sample.current_fit_id)
            chroma_ids = set(fit.inputs["mask_ids"])
            for view in views_of(session, sample.id):
                shown = session.get(Mask, view.mask_id)
                assert shown.kind == MaskKind.model and shown.storage_key == mask_key(view.id, fit.id)
                chroma = session.execute(select(Mask).where(Mask.view_id == view.id,
                                                            Mask.kind == MaskKind.chroma_key)).scalar_one()
                assert chroma.id in chroma_ids  # the fit was made with the chroma key
                shape = (view.height, view.width)
                cut = read_mask(ctx, shown.storage_key, shape, "cut")
                key = read_mask(ctx, chroma.storage_key, shape, "chroma key")
                assert not (cut & ~key).any()  # only removes pixels
                silhouette = read_mask(ctx, fit.diagnostics["model_mask_keys"][str(view.id)], shape, "fit")
                assert not (cut & ~near(silhouette, round(NEAR_SILHOUETTE_PX * view.width / 640) or 1)).any()
                hand = truth[sample.frame_index].hand_masks[view.camera]
                cut_iou.append(iou(cut, hand))
                chroma_iou.append(iou(key, hand))
    assert np.median(cut_iou) > 0.5 > np.median(chroma_iou), (np.median(cut_iou), np.median(chroma_iou))
    with ctx.session_factory() as session:
        ids = list(session.execute(select(Sample.id)).scalars())
    assert record_hand_masks(ctx, ids) == 0  # a redelivery writes nothing twice


def test_samples_without_a_hand_go_to_the_annotators_and_the_reason_is_recorded(world):
    ctx, queue, project_id, fake = world
    fake.no_hand_frames = {1}
    job_id = _launch(ctx, queue, project_id, rest="annotate")
    result = preannotate.run_preannotation_job(ctx, job_id)
    assert result["no_detection"] == 1 and result["fitted"] == 3, result
    assert any("no hand to fit" in e and "0 of 8 views" in e for e in result["errors"].values())
    with ctx.session_factory() as session:
        sample = session.execute(select(Sample).where(Sample.frame_index == 1)).scalar_one()
        assert sample.state == SampleState.needs_annotation and sample.current_fit_id is None


def test_by_default_unpicked_samples_stay_fitted_for_the_next_round(world):
    """The default rest is "keep" (the paper's treatment of unpicked samples): the policy's picks go to the
    reviewers, the others stay fitted and a sample without a hand stays unlabeled; nothing reaches the annotators."""
    ctx, queue, project_id, fake = world
    fake.outliers_by_frame = {0: 0, 1: 1, 2: 2, 3: 3}
    fake.no_hand_frames = {3}
    job_id = _launch(ctx, queue, project_id)
    with ctx.session_factory() as session:
        assert session.get(Job, job_id).payload["rest"] == "keep"
    result = preannotate.run_preannotation_job(ctx, job_id)
    _, _, states = _counts(ctx)
    assert result["to_review"] == 2 and result["fitted_to_annotators"] == 0, result
    assert result["unlabeled_to_annotators"] == 0, result
    assert states == {SampleState.in_review: 2, SampleState.fitted: 1, SampleState.unlabeled: 1}, states


def test_every_detector_fit_is_offered_to_reviewers_within_their_capacity(world):
    """Round 0 with a capacity (the paper's 1,000 of round 1): all the detector's fits reach the reviewers, most
    confident first in their queue; the sample without a hand stays unlabeled for round 1."""
    ctx, queue, project_id, fake = world
    ctx.settings = ctx.settings.model_copy(update={"review_capacity_per_round": 1000})
    fake.outliers_by_frame = {0: 0, 1: 1, 2: 2, 3: 3}  # three different confidences: the median cut would take 2
    fake.no_hand_frames = {3}
    result = preannotate.run_preannotation_job(ctx, _launch(ctx, queue, project_id))
    _, _, states = _counts(ctx)
    assert result["to_review"] == 3 and result["fitted_to_annotators"] == 0, result
    assert states == {SampleState.in_review: 3, SampleState.unlabeled: 1}, states


def test_the_fixed_policy_stays_available(world):
    """review_capacity_per_round 0: the paper's median cut, as before the capacity."""
    ctx, queue, project_id, fake = world
    ctx.settings = ctx.settings.model_copy(update={"review_capacity_per_round": 0})
    fake.outliers_by_frame = {0: 0, 1: 1, 2: 2, 3: 3}  # four different confidences
    result = preannotate.run_preannotation_job(ctx, _launch(ctx, queue, project_id, rest="annotate"))
    assert result["to_review"] == 2 and result["fitted_to_annotators"] == 2, result


@pytest.mark.parametrize(("round0", "later", "reviewed"), [(1000, 0, 3), (0, 1000, 2), (None, 1000, 3)])
def test_round_0_has_its_own_review_capacity_where_set(world, round0, later, reviewed):
    """`preannotation_review_capacity` decides round 0's queue whatever the later rounds' capacity (1000: every fit
    with a hand; 0: the paper's median cut); unset, round 0 follows `review_capacity_per_round`."""
    ctx, queue, project_id, fake = world
    ctx.settings = ctx.settings.model_copy(update={"preannotation_review_capacity": round0,
                                                   "review_capacity_per_round": later})
    fake.outliers_by_frame = {0: 0, 1: 1, 2: 2, 3: 3}  # four different confidences: the median cut takes 2
    fake.no_hand_frames = {3}
    result = preannotate.run_preannotation_job(ctx, _launch(ctx, queue, project_id))
    assert result["to_review"] == reviewed, result


def _with_detector_heuristic(ctx, **thresholds):
    ctx.settings = ctx.settings.model_copy(update={"detector_heuristic": True, **thresholds})


def test_the_detectors_heuristic_accepts_fits_that_meet_it_into_round_0s_d_h(database_url, world):
    """Thresholds every fit of the (fake) detector meets: all four are accepted without a person, as D^h of round 0,
    each with a heuristic decision naming the detector, and the job counts them; nobody is asked to review."""
    from backend.models.enums import Stream
    from backend.models.review import Decision, Round, RoundMember

    ctx, queue, project_id, _fake = world
    _with_detector_heuristic(ctx, detector_heuristic_min_mean_confidence=0.0, detector_heuristic_min_mean_iou=0.0,
                             detector_heuristic_max_low_iou_views=8, detector_heuristic_max_mean_distance_m=1.0,
                             detector_heuristic_max_keypoint_distance_m=1.0)
    result = preannotate.run_preannotation_job(ctx, _launch(ctx, queue, project_id))
    assert result["heuristic"] == {"fits": 4, "evaluated": 4, "accepted": 4}, result
    assert result["to_review"] == 0, result
    _, _, states = _counts(ctx)
    assert states == {SampleState.accepted: 4}, states
    with ctx.session_factory() as session:
        fits = session.execute(select(Fit)).scalars().all()
        assert all(f.heuristic["accepted"] and f.heuristic["estimator"] == "detector" for f in fits)
        members = session.execute(select(RoundMember.stream, Round.index).join(Round)).all()
        assert members == [(Stream.heuristic, 0)] * 4, members
        reasons = session.execute(select(Decision.reason).where(Decision.by_heuristic.is_(True))).scalars().all()
        assert reasons == ["heuristic (detector): all criteria met"] * 4


def test_the_detectors_heuristic_leaves_what_fails_it_to_the_reviewers(world):
    """Default thresholds against a fit whose keypoints the detector did not all lift, and thresholds no fit meets:
    nothing is accepted, each fit says why, and the review policy routes the samples as without the heuristic."""
    ctx, queue, project_id, fake = world
    _with_detector_heuristic(ctx, detector_heuristic_min_mean_confidence=1.0)  # none is above 1
    fake.outliers_by_frame = {0: 0, 1: 1, 2: 2, 3: 3}
    result = preannotate.run_preannotation_job(ctx, _launch(ctx, queue, project_id, rest="annotate"))
    assert result["heuristic"] == {"fits": 4, "evaluated": 4, "accepted": 0}, result
    assert result["to_review"] == 2 and result["fitted_to_annotators"] == 2, result
    with ctx.session_factory() as session:
        for fit in session.execute(select(Fit)).scalars():
            assert not fit.heuristic["accepted"]
            assert any(r.startswith("mean confidence") for r in fit.heuristic["failed"]), fit.heuristic


@pytest.mark.parametrize(("min_training", "to_review"), [(2, 1), (3, 2)])
def test_once_the_heuristic_gave_d0_enough_labels_the_percentile_cuts_round_0s_review(world, monkeypatch,
                                                                                      min_training, to_review):
    """The heuristic accepts the two clean frames (recorded first). Where two labels are enough for round 1
    (`round_min_training_samples` 2), only the other fits from the median up reach the reviewers (capacity for all),
    the other stays fitted for round 1; where they are not (3), every fit is offered, as without the heuristic."""
    from backend.services.review.verification import HeuristicResult
    from workers.tasks import cross_checks

    ctx, queue, project_id, fake = world
    _with_detector_heuristic(ctx)
    ctx.settings = ctx.settings.model_copy(update={"review_capacity_per_round": 1000, "review_percentile_cut": True,
                                                   "round_min_training_samples": min_training})
    fake.outliers_by_frame = {0: 0, 1: 0, 2: 2, 3: 3}  # frames 2 and 3: outlier views, lower confidences
    verdicts = iter([True, True, False, False])
    monkeypatch.setattr(cross_checks, "detector_verdict", lambda *a: HeuristicResult(next(verdicts), (), {}))
    result = preannotate.run_preannotation_job(ctx, _launch(ctx, queue, project_id))
    assert result["heuristic"] == {"fits": 4, "evaluated": 4, "accepted": 2}, result
    assert result["to_review"] == to_review, result
    with ctx.session_factory() as session:
        states = {s.frame_index: s.state for s in session.execute(select(Sample)).scalars()}
    assert states[0] == states[1] == SampleState.accepted and states[2] == SampleState.in_review, states
    assert states[3] == (SampleState.fitted if to_review == 1 else SampleState.in_review), states


def test_a_redelivered_job_records_nothing_twice(database_url, world):
    ctx, queue, project_id, fake = world
    job_id = _launch(ctx, queue, project_id)
    preannotate.run_preannotation_job(ctx, job_id)
    before = _counts(ctx)
    again = preannotate.run_preannotation_job(ctx, job_id)
    assert again == {"job_id": job_id, "skipped": True}
    assert _counts(ctx) == before and fake.calls == 4


def test_a_taken_over_job_continues_from_what_is_recorded(world):
    """A worker died after queueing the first fits: the next attempt fits those and detects only the rest."""
    ctx, queue, project_id, fake = world
    job_id = _launch(ctx, queue, project_id)
    with ctx.session_factory() as session:
        first = session.get(Job, job_id).payload["sample_ids"][0]
    with ctx.session_factory() as session:
        frame = preannotate.load_frames(ctx, session, [first])[first]
        rig = preannotate.rig_of(ctx, session, project_id)
    record, _ = preannotate._detect_sample(ctx, frame, rig, "right")
    assert preannotate._queue_detector_fit(ctx, job_id, first, record) is not None
    result = preannotate.run_preannotation_job(ctx, job_id)
    assert result["fitted"] == 4 and result["detected"] == 3 and fake.calls == 4, result
    fits, _, _ = _counts(ctx)
    assert fits == 4


def test_launch_refuses_without_the_detector_and_writes_nothing(world, monkeypatch):
    ctx, queue, project_id, _ = world
    monkeypatch.setattr(preannotation, "detector_problem", lambda: MISSING)
    before = _counts(ctx)
    with pytest.raises(ServiceUnavailableError, match="hand landmark model file is missing"):
        _launch(ctx, queue, project_id)
    assert _counts(ctx) == before and queue.enqueued == []


def test_a_queued_job_whose_detector_vanished_fails_with_its_sentence_and_changes_no_sample(world, monkeypatch):
    ctx, queue, project_id, fake = world
    job_id = _launch(ctx, queue, project_id)
    monkeypatch.setattr(preannotation, "detector_problem", lambda: MISSING)
    result = preannotate.run_preannotation_job(ctx, job_id)
    assert result["failed"] == MISSING and fake.calls == 0
    fits, _, states = _counts(ctx)
    assert fits == 0 and states == {SampleState.unlabeled: 4}
    with ctx.session_factory() as session:
        job = session.get(Job, job_id)
        assert job.state == JobState.failed and job.error == MISSING


def _bare_project(ctx, cameras: int) -> int:
    with ctx.session_factory.begin() as session:
        project = Project(name=f"bare-{cameras}", hand_model="builtin", synthetic=True, description="")
        session.add(project)
        session.flush()
        for i in range(cameras):
            session.add(CameraCalibration(project_id=project.id, name=f"cam{i}", width=160, height=120,
                                          K=np.eye(3).tolist(), dist=[0.0] * 5, R=np.eye(3).tolist(),
                                          t=[0.0, 0.0, 1.0]))
        return project.id


@pytest.mark.parametrize(("cameras", "message"), [(0, "has no camera calibration"), (1, "1 calibrated view")])
def test_bad_calibration_is_refused_at_launch_and_by_the_job(database_url, world, cameras, message):
    ctx, queue, _, fake = world
    bare = _bare_project(ctx, cameras)
    before = _counts(ctx)
    with pytest.raises(InvalidInputError, match=message):
        _launch(ctx, queue, bare)
    assert _counts(ctx) == before
    # A job row made some other way (an older server, an edited payload) fails the same way, writing nothing.
    with ctx.session_factory.begin() as session:
        job_id = jobs.create(session, queue, JobKind.preannotate, payload={"project_id": bare, "sample_ids": [1],
                                                                            "rest": "annotate"}).id
    result = preannotate.run_preannotation_job(ctx, job_id)
    assert message in result["failed"] and fake.calls == 0
    fits, _, states = _counts(ctx)
    assert fits == 0 and states == {SampleState.unlabeled: 4}


def test_launch_refuses_wrong_ids_and_a_second_job(world):
    ctx, queue, project_id, _ = world
    with pytest.raises(NotFoundError, match="project 999 not found"):
        _launch(ctx, queue, 999)
    with pytest.raises(NotFoundError, match="samples not in project"):
        _launch(ctx, queue, project_id, sample_ids=[1, 12345])
    with pytest.raises(InvalidInputError, match="rest must be one of"):
        _launch(ctx, queue, project_id, rest="discard")
    job_id = _launch(ctx, queue, project_id, sample_ids=[1, 2])
    with pytest.raises(ConflictError, match=f"already being pre-annotated \\(job {job_id}"):
        _launch(ctx, queue, project_id)
    preannotate.run_preannotation_job(ctx, job_id)
    with pytest.raises(ConflictError, match="only unlabeled samples can be pre-annotated: 1 is"):
        _launch(ctx, queue, project_id, sample_ids=[1, 3])
    _, _, states = _counts(ctx)
    assert states[SampleState.unlabeled] == 2  # the job touched only the samples it was given


def test_a_cancelled_job_stops_and_leaves_no_sample_fitting(world, monkeypatch):
    ctx, queue, project_id, fake = world
    job_id = _launch(ctx, queue, project_id, rest="annotate")
    real = fake.__call__

    def cancel_midway(*args, **kwargs):
        out = real(*args, **kwargs)
        if fake.calls == 2:
            with ctx.session_factory.begin() as session:
                jobs.cancel(session, queue, job_id, None)
        return out

    monkeypatch.setattr(preannotate, "detect", cancel_midway)
    result = preannotate.run_preannotation_job(ctx, job_id)
    assert result.get("cancelled") is True, result
    _, _, states = _counts(ctx)
    assert SampleState.fitting not in states and SampleState.unlabeled not in states, states


def test_the_celery_task_calls_the_service(monkeypatch, tmp_path):
    import sys

    from backend.settings import get_settings

    if "workers.tasks.app" not in sys.modules:  # its import makes the embedded broker's folders: not in the tree
        monkeypatch.setenv("HANDLOOP_DATA_DIR", str(tmp_path))
        get_settings.cache_clear()
    from workers.tasks import definitions

    get_settings.cache_clear()  # the next reader sees the environment as it is after this test

    seen = []
    monkeypatch.setattr(definitions, "get_context", lambda: "ctx")
    monkeypatch.setattr(preannotate, "run_preannotation_job", lambda ctx, job_id: seen.append((ctx, job_id)) or {})
    assert definitions.preannotate.run("7") == {}
    assert seen == [("ctx", 7)]


def test_the_settings_default_is_off():
    assert Settings(environment="test", secret_key="x" * 20).preannotate_on_import is False


def test_a_frame_that_breaks_the_detector_goes_to_the_annotators_and_the_others_are_fitted(world, monkeypatch):
    ctx, queue, project_id, fake = world

    def flaky(images, *args, **kwargs):
        if fake.calls == 1:  # the second frame
            fake.calls += 1
            raise RuntimeError("interpreter tensor 3 has the wrong size")
        return fake(images, *args, **kwargs)

    monkeypatch.setattr(preannotate, "detect", flaky)
    result = preannotate.run_preannotation_job(ctx, _launch(ctx, queue, project_id, rest="annotate"))
    assert result["fitted"] == 3 and result["no_detection"] == 1, result
    assert any("detector failed: RuntimeError: interpreter tensor 3" in e for e in result["errors"].values())
    _, _, states = _counts(ctx)
    assert states.get(SampleState.needs_annotation, 0) >= 1 and SampleState.unlabeled not in states


def test_model_files_vanishing_mid_job_fail_it_with_the_reason_and_leave_no_sample_between(world, monkeypatch):
    ctx, queue, project_id, fake = world

    def vanishing(images, *args, **kwargs):
        if fake.calls == 2:
            raise preannotate.DetectorUnavailableError("hand_landmark_full.tflite: checksum mismatch")
        return fake(images, *args, **kwargs)

    monkeypatch.setattr(preannotate, "detect", vanishing)
    job_id = _launch(ctx, queue, project_id, rest="annotate")
    result = preannotate.run_preannotation_job(ctx, job_id)
    assert result["failed"] == "hand_landmark_full.tflite: checksum mismatch"
    with ctx.session_factory() as session:
        job = session.get(Job, job_id)
        assert job.state == JobState.failed and "checksum mismatch" in job.error
    fits, _, states = _counts(ctx)
    # The two detected samples' fits were queued but not run: cancelled, and every sample is with the annotators.
    assert fits == 0 and states == {SampleState.needs_annotation: 4}, states


def test_observations_keep_the_inlier_detections_inside_the_image_weighted_by_score_and_presence():
    from workers.geometry.rig import default_rig

    cameras = list(default_rig(width_px=160))[:3]
    xy = np.full((21, 2), 50.0)
    xy[3] = (-5.0, 10.0)  # outside the image: left out
    views = [{"keypoints_px": xy.tolist(), "scores": [0.5] * 21, "presence": 0.8} for _ in cameras]
    views[2] = None  # no hand in the third view
    inliers = np.ones((21, 3), bool)
    inliers[7, 1] = False  # view 1 disagreed on keypoint 7
    points = np.zeros((21, 3))
    points[9] = np.nan  # not lifted
    from workers.tasks.fits import json_safe  # as the record is stored: NaN as None

    record = json_safe({"views": views, "inliers": inliers.tolist(), "points_world": points,
                        "confidence": [0.7] * 9 + [float("nan")] + [0.7] * 11})
    obs = detection_inputs.observations_from_detection(record, cameras, None)
    assert obs.click_weights.shape == (3, 21) and obs.click_weights[0, 0] == pytest.approx(0.4)
    assert obs.click_weights[0, 3] == 0 and obs.click_weights[1, 7] == 0 and obs.click_weights[0, 7] > 0
    assert not obs.click_weights[2].any()
    assert obs.keypoint_3d_weights[9] == 0 and obs.keypoint_3d_weights[0] == pytest.approx(0.7)
    assert obs.points_source == "detector" and obs.from_proposal is None  # not points placed by hand
    obs.validate(cameras)  # what the fit engine checks first
    with pytest.raises(preannotate.InputError, match="covers 3 views; the rig has 2"):
        detection_inputs.observations_from_detection(record, cameras[:2], None)


def test_the_detector_looks_for_each_sequences_hand_unless_the_admin_names_one(tmp_path, capture_cache, monkeypatch):
    """A left-hand capture: without `handedness` the detector is asked for left hands (the sequence's side);
    an explicit "right" overrides it."""
    capture = tiny_capture(capture_cache, frames=2, side="left")
    settings = Settings(data_dir=tmp_path / "data", review_min_time_gap_s=0.0, review_min_pose_distance=0.0,
                        **TEST_SETTINGS)
    project_id = prepare_database(settings, capture, queue_for_annotation=False)
    queue = InMemoryJobQueue()
    ctx = build_context(settings, job_queue=queue)
    fake = FakeDetector(capture)
    asked: list[str] = []

    def spy(images, cameras, masks=None, *, handedness="right"):
        asked.append(handedness)
        return fake(images, cameras, masks, handedness=handedness)

    monkeypatch.setattr(preannotate, "detect", spy)
    monkeypatch.setattr(preannotation, "detector_problem", lambda: None)
    try:
        with ctx.session_factory() as session:
            samples = list(session.execute(select(Sample.id).order_by(Sample.id)).scalars())
        preannotate.run_preannotation_job(ctx, _launch(ctx, queue, project_id, sample_ids=samples[:1]))
        preannotate.run_preannotation_job(ctx, _launch(ctx, queue, project_id, sample_ids=samples[1:],
                                                       handedness="right"))
        assert asked == ["left", "right"]
        with ctx.session_factory() as session:
            fits = session.execute(select(Fit).order_by(Fit.id)).scalars().all()
            assert [f.diagnostics["hand_side"] for f in fits] == ["left", "left"]  # the fit follows the sequence
            for fit in fits:  # residuals to the detector's keypoints, not to clicks
                by_origin = fit.diagnostics["residual_2d_by_origin"]
                assert by_origin["clicked"]["n"] == 0 and by_origin["detector"]["n"] > 0, by_origin
                assert fit.diagnostics["mean_residual_2d_of"] == "detector"
                assert fit.diagnostics["mean_residual_2d_px"] == by_origin["detector"]["mean_px"]
    finally:
        ctx.session_factory.kw["bind"].dispose()


def test_a_sequence_whose_hands_look_like_the_other_side_is_noted(tmp_path, capture_cache, monkeypatch):
    """A left-hand capture detected as right hands (the admin named "right"): the detected hands' chirality says
    left in every frame, and the job's result says so for the sequence (issue 36)."""
    capture = tiny_capture(capture_cache, frames=3, side="left")
    settings = Settings(data_dir=tmp_path / "data", review_min_time_gap_s=0.0, review_min_pose_distance=0.0,
                        **TEST_SETTINGS)
    project_id = prepare_database(settings, capture, queue_for_annotation=False)
    queue = InMemoryJobQueue()
    ctx = build_context(settings, job_queue=queue)
    monkeypatch.setattr(preannotate, "detect", FakeDetector(capture, outlier_views=0))
    monkeypatch.setattr(preannotation, "detector_problem", lambda: None)
    try:
        with ctx.session_factory() as session:
            samples = list(session.execute(select(Sample.id).order_by(Sample.id)).scalars())
        result = preannotate.run_preannotation_job(ctx, _launch(ctx, queue, project_id, sample_ids=samples,
                                                                handedness="right"))
        (note,) = result["handedness"].values()
        assert "left hand in 3 of 3 frames" in note and "a right hand was asked for" in note
    finally:
        ctx.session_factory.kw["bind"].dispose()
