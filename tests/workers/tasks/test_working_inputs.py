"""A 2048 px capture with a 512 px working width (issue 18): the detector (pre-annotation), HandSegNet / MVNet
(prediction) and the training set read the working copies with the cameras scaled alike; what they give back
is in full-resolution pixels (detector keypoints, HandSegNet masks), so fits and stored masks line up with the
2048 px views.

The source is a small synthetic capture whose images are upscaled to 2048 px and assembled with
`assemble_capture` (green screen keyed); its ground truth's 3D keypoints give the expected pixels."""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from sqlalchemy import select

from backend.models.capture import Project, View
from backend.models.fits import Fit
from backend.services.jobs.jobs import InMemoryJobQueue
from backend.services.rounds import preannotation
from backend.services.transactions import run_after_commit
from backend.settings import Settings
from tests.support.live_stack import TEST_SETTINGS, prepare_database, tiny_capture
from workers.capture import load_frame_images, load_frame_masks, load_ground_truth, read_capture
from workers.capture.assemble import assemble_capture
from workers.capture.working import DERIVED_PREFIX
from workers.detector.types import LiftedKeypoints, ViewKeypoints
from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig
from workers.geometry.triangulation import triangulate
from workers.tasks import inference, preannotate, records
from workers.tasks.context import build_context
from workers.tasks.inputs import load_frames, rig_of
from workers.tasks.working_inputs import (
    WorkingRig,
    lifted_at_full_resolution,
    working_frames,
    working_mask_dicts,
    working_rig,
    working_rig_record,
)

FULL_WIDTH, WORKING_WIDTH = 2048, 512


@dataclass
class World:
    ctx: object
    queue: InMemoryJobQueue
    project_id: int
    truth: list[np.ndarray]  # per frame index (21, 3) metres, world frame
    full: list  # the 2048 px cameras
    source_cam0: list[np.ndarray] = field(default_factory=list)  # per frame cam0's image at the working size


@pytest.fixture
def world(tmp_path: Path, capture_cache: Path):
    source = read_capture(tiny_capture(capture_cache, frames=2, width=256))
    full = [c.scaled(FULL_WIDTH) for c in source.cameras]
    frames = source.sequences[0].frames
    folders = tmp_path / "frames"
    for frame in frames:
        images = load_frame_images(frame, source.cameras)
        for cam in full:
            (folders / cam.name).mkdir(parents=True, exist_ok=True)
            big = cv2.resize(images[cam.name], (cam.width, cam.height), interpolation=cv2.INTER_CUBIC)
            cv2.imwrite(str(folders / cam.name / f"{frame.index:03d}.jpg"), cv2.cvtColor(big, cv2.COLOR_RGB2BGR),
                        [cv2.IMWRITE_JPEG_QUALITY, 90])
    capture = tmp_path / "capture"
    assemble_capture(full, capture, images=folders, green_screen=True, working_width_px=WORKING_WIDTH, workers=1)
    shutil.rmtree(folders)
    settings = Settings(data_dir=tmp_path / "data", review_min_time_gap_s=0.0, review_min_pose_distance=0.0,
                        **TEST_SETTINGS)
    project_id = prepare_database(settings, capture, queue_for_annotation=False)
    queue = InMemoryJobQueue()
    ctx = build_context(settings, job_queue=queue)
    small0 = full[0].scaled(WORKING_WIDTH)
    cam0 = [cv2.resize(load_frame_images(f, source.cameras)[full[0].name], (small0.width, small0.height),
                       interpolation=cv2.INTER_AREA) for f in frames]
    yield World(ctx, queue, project_id, [load_ground_truth(f).keypoints_3d for f in frames], full, cam0)
    ctx.session_factory.kw["bind"].dispose()


class WorkingSizeDetector:
    """Stands in for workers.detector.detect_frame: checks it is given working-size views, answers with the true
    keypoints projected with the cameras it was given (the working cameras), lifted by the real triangulation."""

    def __init__(self, w: World) -> None:
        self.world, self.seen = w, []

    def __call__(self, images, cameras, masks=None, *, handedness="right") -> LiftedKeypoints:
        self.seen.append(([im.shape for im in images], [(c.width, c.height) for c in cameras],
                          None if masks is None else [None if m is None else m.shape for m in masks]))
        errors = [np.abs(images[0].astype(int) - ref.astype(int)).mean() for ref in self.world.source_cam0]
        index = int(np.argmin(errors))
        pixels, _ = project_points(self.world.truth[index], list(cameras))
        views = tuple(ViewKeypoints(px, np.full(21, 0.9), 0.95, handedness,
                                    np.array([px[:, 0].min(), px[:, 1].min(), np.ptp(px[:, 0]), np.ptp(px[:, 1])]),
                                    0.0) for px in pixels)
        tri = triangulate(pixels, list(cameras), outlier_px=8.0)
        return LiftedKeypoints(tri.points_world, np.where(tri.valid, 0.95, np.nan), tri.inliers.T.copy(),
                               tri.reprojection_px, views)


def test_the_project_keeps_full_resolution_views_and_its_working_width(world: World) -> None:
    with world.ctx.session_factory() as session:
        assert session.get(Project, world.project_id).working_width_px == WORKING_WIDTH
        sizes = set(session.execute(select(View.width, View.height)).all())
    assert sizes == {(c.width, c.height) for c in world.full} and {w for w, _ in sizes} == {FULL_WIDTH}


def test_detector_reads_working_copies_and_its_keypoints_come_back_in_full_pixels(world: World, monkeypatch) -> None:
    fake = WorkingSizeDetector(world)
    monkeypatch.setattr(preannotate, "detect", fake)
    monkeypatch.setattr(preannotation, "detector_problem", lambda: None)
    with world.ctx.session_factory() as session:
        job_id = preannotation.launch(session, world.queue, world.project_id, actor_id=None).id
        session.commit()
        run_after_commit(session)
    result = preannotate.run_preannotation_job(world.ctx, job_id)
    assert result["detected"] == 2 and result["fitted"] == 2, result
    small = [c.scaled(WORKING_WIDTH) for c in world.full]
    assert len(fake.seen) == 2
    for shapes, sizes, mask_shapes in fake.seen:
        assert shapes == [(c.height, c.width, 3) for c in small]  # the detector's input: the working copies
        assert sizes == [(c.width, c.height) for c in small]  # with the cameras scaled alike
        assert mask_shapes == [(c.height, c.width) for c in small]
    derived = sorted((world.ctx.settings.storage_dir / DERIVED_PREFIX / f"w{WORKING_WIDTH}").rglob("*.jpg"))
    assert len(derived) == 2 * 8  # derived once per view, beside the originals
    # The detector's masks come from masks_for: no working copies of the chroma-key masks are made for it.
    assert not list((world.ctx.settings.storage_dir / DERIVED_PREFIX).rglob("*.png"))
    with world.ctx.session_factory() as session:
        fits = session.execute(select(Fit).order_by(Fit.sample_id)).scalars().all()
        assert len(fits) == 2
        rig = rig_of(world.ctx, session, world.project_id)
        for fit, truth in zip(fits, world.truth, strict=True):
            expected, _ = project_points(truth, list(rig.cameras))  # full-resolution pixels of the 2048 px views
            stored = np.array([v["keypoints_px"] for v in fit.inputs["detection"]["views"]], float)
            np.testing.assert_allclose(stored, expected, atol=0.011)  # records keep 0.01 px
            residual = np.asarray(fit.inputs["detection"]["reprojection_px"], float)
            assert np.isfinite(residual).all() and residual.max() < 0.05  # exact pixels: no residual
            assert np.abs(stored - expected / 4).max() > 100  # not working pixels
            # The fit made from them lands on the hand in the full-resolution rig.
            assert 1000 * np.linalg.norm(np.asarray(fit.keypoints_m) - truth, axis=1).mean() < 10.0


def test_networks_read_working_copies_and_masks_come_back_at_full_size(world: World, monkeypatch) -> None:
    import workers.nets.predict as predict_module
    from workers.nets.predict import FramePrediction, KeypointPrediction

    seen = []

    def fake_predict_frames(mvnet, frames, cameras, handsegnet=None, batch_frames=4, *, handedness="right",
                            detection_cache=None):
        maps = []
        for frame in frames:
            images = load_frame_images(frame, cameras)  # refuses images of another size than the cameras'
            chroma = load_frame_masks(frame)
            seen.append(([images[c.name].shape for c in cameras], [chroma[c.name].shape for c in cameras],
                         [(c.width, c.height) for c in cameras]))
            maps.append([chroma[c.name].astype(np.float32) for c in cameras])  # HandSegNet's maps: working size
        N = len(frames)
        keypoints = KeypointPrediction(np.stack(world.truth[:N]), np.full((N, 21), 0.9), np.full(N, 0.9),
                                       np.zeros((N, 3)))
        return FramePrediction(keypoints, maps, [None] * N)

    monkeypatch.setattr(predict_module, "predict_frames", fake_predict_frames)
    ctx = world.ctx
    with ctx.session_factory() as session:
        rig = rig_of(ctx, session, world.project_id)
        frames = list(load_frames(ctx, session, [1, 2]).values())
        wrig = working_rig(session, rig)
    small = wrig.cameras
    assert wrig.reduced and [(c.width, c.height) for c in small] == [(WORKING_WIDTH, round(c.height / 4))
                                                                     for c in world.full]
    out = inference._predict(ctx, object(), object(), working_frames(ctx, frames, wrig), wrig)
    expected = ([(c.height, c.width, 3) for c in small], [(c.height, c.width) for c in small],
                [(c.width, c.height) for c in small])
    assert len(seen) == 2 and all(s == expected for s in seen)
    for frame, maps in zip(frames, out.masks, strict=True):
        originals = load_frame_masks(frame.frame)  # the full-resolution chroma-key masks
        for cam, prob in zip(rig.cameras, maps, strict=True):
            assert prob.shape == (cam.height, cam.width)
            got, want = prob > 0.5, originals[cam.name]
            assert (got & want).sum() / (got | want).sum() > 0.9
    with ctx.session_factory.begin() as session:  # storable as the views' masks (the shape is checked there)
        prediction = records.record_prediction(
            session, ctx.storage, frames[0].sample_id, keypoints_m=world.truth[0].tolist(),
            confidences=[0.9] * 21, mvnet_version="round-001/mvnet", handsegnet_version="round-001/handsegnet",
            masks={v: m > 0.5 for v, m in zip(frames[0].view_ids, out.masks[0], strict=True)})
        assert prediction.id is not None


def test_training_inputs_are_scaled_alike(world: World) -> None:
    ctx = world.ctx
    with ctx.session_factory() as session:
        rig = rig_of(ctx, session, world.project_id)
        frames = list(load_frames(ctx, session, [1]).values())
        wrig = working_rig(session, rig)
    working = working_rig_record(rig, wrig)
    assert working.cameras == wrig.cameras and working.digest != rig.digest
    [frame] = working_frames(ctx, frames, wrig)
    images = load_frame_images(frame.frame, working.cameras)  # sizes checked against the working cameras
    assert [images[c.name].shape for c in wrig.cameras] == [(c.height, WORKING_WIDTH, 3) for c in wrig.cameras]
    full_masks = load_frame_masks(frames[0].frame)
    [masks] = working_mask_dicts([full_masks], wrig)
    for cam in wrig.cameras:
        assert masks[cam.name].shape == (cam.height, cam.width) and masks[cam.name].dtype == bool
    unreduced = replace(wrig, width=None, cameras=wrig.full)
    assert working_frames(ctx, frames, unreduced) == frames and working_rig_record(rig, unreduced) is rig


def test_residuals_are_full_resolution_pixels_in_a_rig_of_mixed_widths() -> None:
    """Cameras of 2048 and 1024 px read at 512 px: the detector's residual, a median over views, comes back in
    each view's own full-resolution pixels (the factor is 4 in one and 2 in the other)."""
    full = tuple(c.scaled(2048 if i % 2 else 1024) for i, c in enumerate(default_rig(None)))
    wrig = WorkingRig(512, full, tuple(c.scaled(512) for c in full))
    truth = np.random.default_rng(5).normal(0.0, 0.05, (21, 3))
    pixels, _ = project_points(truth, list(wrig.cameras))
    pixels += np.random.default_rng(6).normal(0.0, 1.0, pixels.shape)  # working pixels, 1 px noise
    views = tuple(ViewKeypoints(px, np.full(21, 0.9), 0.95, "right", np.array([0.0, 0.0, 50.0, 40.0]), 0.0)
                  for px in pixels)
    tri = triangulate(pixels, list(wrig.cameras), outlier_px=100.0)
    lifted = LiftedKeypoints(tri.points_world, np.full(21, 0.9), tri.inliers.T.copy(), tri.median_reprojection_px,
                             views)
    out = lifted_at_full_resolution(lifted, wrig)
    reprojected, _ = project_points(tri.points_world, list(full))
    detected = np.stack([v.keypoints_px for v in out.views])
    expected = np.median(np.linalg.norm(reprojected - detected, axis=2), axis=0)  # every view an inlier
    assert tri.inliers.all()
    np.testing.assert_allclose(out.reprojection_px, expected, rtol=1e-9)
    assert not np.allclose(out.reprojection_px, 4 * lifted.reprojection_px, rtol=0.05)
    for view, small, big in zip(out.views, wrig.cameras, full, strict=True):  # boxes: each axis its own factor
        factor = np.array([big.width / small.width, big.height / small.height])
        np.testing.assert_allclose(view.box_px, [*(0.5 * factor - 0.5), *([50.0, 40.0] * factor)], rtol=1e-12)
