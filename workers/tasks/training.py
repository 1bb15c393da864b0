"""Training jobs of a round: HandSegNet and MVNet on the accepted samples D_i.

Labels come from the accepted samples' fits, never from ground truth: MVNet learns the fits' 3D keypoints,
HandSegNet the fitted model's masks (stored with each fit; rendered from its parameters when missing).
Checkpoints go to <data_dir>/checkpoints/round-NNN/ (workers/nets/checkpoints.py), versioned
"round-NNN/<net>"; training resumes from its partial checkpoint when the job is taken over, and starts from
the latest earlier round's checkpoint of the same architecture (warm start, recorded as "init_from" in the
checkpoint's metadata), so the networks accumulate training over the rounds.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from celery.exceptions import SoftTimeLimitExceeded
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.enums import JobState
from backend.models.fits import Fit
from backend.models.jobs import Job
from backend.models.review import Round, RoundMember
from backend.services.errors import DomainError
from backend.services.jobs import jobs
from backend.settings import Settings
from workers.handmodel.params import HandParams
from workers.handmodel.posed import posed_mesh
from workers.nets.configs import CONFIGS, get_config
from workers.nets.detections import (
    DetectionCache,
    chroma_masks,
    detect_frames,
    detector_backed,
    learn_detector_offsets,
)
from workers.tasks import round_progress
from workers.tasks.context import WorkerContext
from workers.tasks.inputs import InputError, Rig, SampleFrame, capture_for, load_frames, read_mask, rig_of
from workers.tasks.json_values import json_safe
from workers.tasks.progress import JobCancelledError, ProgressReporter
from workers.tasks.working_inputs import working_frames, working_mask_dicts, working_rig, working_rig_record

log = logging.getLogger(__name__)

NETS = ("handsegnet", "mvnet")


def version_of(round_index: int, net: str) -> str:
    """The version name of a round's network: its checkpoint's path below the checkpoints folder."""
    return f"round-{round_index:03d}/{net}"


def checkpoint_of(ctx: WorkerContext, version: str) -> Path:
    """The checkpoint file of a version name (ValueError for a malformed name)."""
    parts = version.split("/")
    if len(parts) != 2 or not parts[0].startswith("round-") or parts[1] not in NETS:
        raise ValueError(f"model version {version!r} is not of the form 'round-NNN/<{'|'.join(NETS)}>'")
    return ctx.settings.checkpoints_dir.resolve() / parts[0] / f"{parts[1]}.pt"


@dataclass(frozen=True, eq=False)
class TrainingSet:
    """Accepted samples of one rig with their fits' labels.

    Attributes:
        rig: the cameras the samples were seen from.
        frames: the samples' frames (stored images; chroma-key masks for cut-and-paste).
        fit_ids: the accepted fit of each sample.
        keypoints_3d: (M, 21, 3) the fits' keypoints, metres, world frame.
        sample_ids: database ids.
        left_out: samples of other rigs (a round trains on one rig), by count.
    """

    rig: Rig
    frames: list[SampleFrame]
    fit_ids: list[int]
    keypoints_3d: np.ndarray
    sample_ids: list[int]
    left_out: int

    def __len__(self) -> int:
        return len(self.sample_ids)


def training_set(ctx: WorkerContext, session: Session, up_to_round_index: int) -> TrainingSet:
    """D_{i}: members of rounds 0 ... up_to_round_index with their fits; the largest rig's samples."""
    rows = session.execute(
        select(RoundMember.sample_id, RoundMember.fit_id).join(Round, Round.id == RoundMember.round_id)
        .where(Round.index <= up_to_round_index, RoundMember.fit_id.is_not(None)).order_by(RoundMember.sample_id)
    ).all()
    if not rows:
        raise InputError(f"no accepted samples in rounds up to {up_to_round_index}: nothing to train on")
    frames = load_frames(ctx, session, [r.sample_id for r in rows])
    by_project: dict[int, list[int]] = {}
    for sample_id, frame in frames.items():
        by_project.setdefault(frame.project_id, []).append(sample_id)
    project_id = max(by_project, key=lambda p: len(by_project[p]))
    chosen = set(by_project[project_id])
    fit_of = {r.sample_id: r.fit_id for r in rows if r.sample_id in chosen}
    ids = sorted(fit_of)
    fits = {f.id: f for f in session.execute(select(Fit).where(Fit.id.in_(list(fit_of.values())))).scalars()}
    keypoints = np.stack([np.asarray(fits[fit_of[s]].keypoints_m, np.float32) for s in ids])
    return TrainingSet(rig_of(ctx, session, project_id), [frames[s] for s in ids], [fit_of[s] for s in ids],
                       keypoints, ids, len(rows) - len(ids))


def model_masks(ctx: WorkerContext, session: Session, tset: TrainingSet) -> list[dict[str, np.ndarray]]:
    """Per sample, camera name -> the accepted fit's model mask (stored, or rendered from its parameters)."""
    fits = {f.id: f for f in session.execute(select(Fit).where(Fit.id.in_(tset.fit_ids))).scalars()}
    out = []
    for frame, fit_id in zip(tset.frames, tset.fit_ids, strict=True):
        fit = fits[fit_id]
        keys = (fit.diagnostics or {}).get("model_mask_keys") or {}
        masks: dict[str, np.ndarray] = {}
        try:
            for cam, view_id in zip(tset.rig.cameras, frame.view_ids, strict=True):
                key = keys.get(str(view_id))
                if key is None:
                    raise InputError(f"fit {fit_id} has no stored mask of view {view_id}")
                masks[cam.name] = read_mask(ctx, key, (cam.height, cam.width), f"fit {fit_id}")
        except InputError:
            masks = render_masks(ctx, tset.rig, np.asarray(fit.params, np.float64), frame.side)
        out.append(masks)
    return out


def render_masks(ctx: WorkerContext, rig: Rig, theta: np.ndarray, side: str = "right") -> dict[str, np.ndarray]:
    """Silhouettes of `side`'s hand model with parameters theta (61,) in every camera of the rig."""
    from workers.rendering import model_mask  # deferred: torch only where a job computes (round_steps, fits)

    arrays = ctx.hand_model(side)
    mesh = posed_mesh(arrays, HandParams.from_theta(theta))
    return {cam.name: model_mask(mesh.vertices, arrays.faces, cam) for cam in rig.cameras}


def _round_of(session: Session, job: Job) -> tuple[Round, Job]:
    round_job = session.get(Job, (job.payload or {}).get("round_job_id"))
    round_ = session.get(Round, job.round_id) if job.round_id is not None else None
    if round_job is None or round_ is None:
        raise InputError(f"train job {job.id} belongs to no round job")
    return round_, round_job


# The hand the rounds' networks and the detector work on (the worker loads the right-hand model).
ROUND_HANDEDNESS = "right"


def round_nets_config(ctx: WorkerContext) -> tuple[Any, str | None]:
    """The configuration a round trains: `<nets_config>-detector` when settings.mvnet_detector is on, such a
    configuration exists and the detector is installed; else `nets_config` (paper-only). Returns it and, where
    the detector was wanted but is missing, the sentence saying why (detections.detector_backed)."""
    name = ctx.settings.nets_config
    if ctx.settings.mvnet_detector and f"{name}-detector" in CONFIGS:
        return detector_backed(get_config(f"{name}-detector"))
    return get_config(name), None


def detection_cache(ctx: WorkerContext) -> Any:
    """Where the rounds keep per-frame detections (beside the checkpoints): each frame is detected once."""
    return DetectionCache(ctx.settings.checkpoints_dir.resolve() / "detections")


def run_training_job(ctx: WorkerContext, job_id: int) -> dict[str, Any]:
    """Claim a train job, train its network on the round's D_i, record the version. Never raises for a
    training that cannot run: the job (and its round job) is marked failed with the reason."""

    with ctx.session_factory.begin() as session:
        job = ctx.claim(session, job_id)
        if job is None:
            return {"job_id": job_id, "skipped": True}
        net = (job.payload or {}).get("net")
        round_job_id = (job.payload or {}).get("round_job_id")
    try:
        with ctx.session_factory() as session:
            if net not in NETS:
                raise InputError(f"train job {job_id} names no network ({net!r})")
            round_, round_job = _round_of(session, session.get(Job, job_id))
            up_to = int((round_job.payload or {}).get("train_on_rounds_up_to", round_.index - 1))
            tset = training_set(ctx, session, up_to)
            if len(tset) < ctx.settings.round_min_training_samples:
                raise InputError(f"{len(tset)} accepted samples in rounds up to {up_to}; a round needs at least "
                                 f"{ctx.settings.round_min_training_samples} (HANDLOOP_ROUND_MIN_TRAINING_SAMPLES)")
            # HandSegNet learns the masks; MVNet's training crops are centred on them (as prediction crops are
            # on HandSegNet's masks), not on the mean keypoint.
            labels_masks = model_masks(ctx, session, tset)
            # The networks read the working copies, with the cameras and the label masks scaled alike.
            wrig = working_rig(session, tset.rig)
            labels_masks = working_mask_dicts(labels_masks, wrig)
            round_index = round_.index
        config, detector_note = round_nets_config(ctx)
        folder = ctx.settings.checkpoints_dir.resolve() / f"round-{round_index:03d}"
        budget = ctx.settings.round_handsegnet_budget_s if net == "handsegnet" else ctx.settings.round_mvnet_budget_s
        reporter = ProgressReporter(ctx, [job_id], round_of=int(round_job_id))  # training: elapsed share of its budget
        reporter(0.0, f"{net}: preparing {len(tset)} samples", force=True)
        tset = dataclasses.replace(tset, rig=working_rig_record(tset.rig, wrig), frames=working_frames(
            ctx, tset.frames, wrig, lambda n: reporter(0.0, f"{net}: working copies of {n}/{len(tset)} samples")))
        result = _train(ctx, net, tset, labels_masks, config, budget, folder, reporter,
                        seed=ctx.settings.round_seed + round_index,
                        extra={"round_index": round_index, "round_job_id": round_job_id,
                               "train_on_rounds_up_to": up_to, "hand_model": ctx.hand_model().name})
        version = version_of(round_index, net)
        outcome = {"job_id": job_id, "net": net, "version": version, "samples": len(tset),
                   "left_out_other_rigs": tset.left_out, "steps": result.metadata.get("steps"),
                   "train_seconds": result.metadata.get("train_seconds"),
                   "train_loss": result.metadata.get("metrics", {}).get("train_loss"),
                   "init_from": (result.metadata.get("init_from") or {}).get("path")}
        if net == "mvnet":
            outcome["heatmap_source"] = config.mvnet.heatmap_source
            if detector_note:
                outcome["detector_status"] = detector_note
        with ctx.session_factory.begin() as session:
            round_row = session.get(Round, session.get(Job, job_id).round_id)
            setattr(round_row, f"{net}_version", version)
            jobs.finish(session, job_id, JobState.succeeded, result=json_safe(outcome))
        log.info("trained %s: %s", net, outcome)
        return outcome
    except JobCancelledError:
        return {"job_id": job_id, "cancelled": True}
    except (InputError, DomainError, ValueError, SoftTimeLimitExceeded) as exc:
        message = getattr(exc, "message", None) or str(exc) or exc.__class__.__name__
        if isinstance(exc, SoftTimeLimitExceeded):
            message = f"time limit of {ctx.settings.task_time_limit_s} s exceeded"
        log.warning("training job %s failed: %s", job_id, message)
        fail_with_round(ctx, job_id, round_job_id, f"training {net}: {message}")
        return {"job_id": job_id, "failed": message}


def warm_start_of(ctx: WorkerContext, net: str, config: Any, round_index: int) -> Path | None:
    """The final checkpoint of `net` from the latest earlier round with the same architecture (training then
    continues from it, so the networks accumulate over rounds), or None (round 1, another configuration)."""
    from workers.nets.checkpoints import previous_checkpoint  # deferred: torch, as in render_masks

    sub = config.mvnet if net == "mvnet" else config.handsegnet
    return previous_checkpoint(ctx.settings.checkpoints_dir.resolve(), net, sub, round_index)  # type: ignore[arg-type]


def _train(ctx: WorkerContext, net: str, tset: TrainingSet, masks: list[dict[str, np.ndarray]] | None, config: Any,
           budget: float, folder: Path, reporter: ProgressReporter, seed: int, extra: dict[str, Any]) -> Any:
    # deferred: torch, as in render_masks
    from workers.nets.data import build_handseg_dataset, build_mvnet_dataset
    from workers.nets.train import train_handsegnet, train_mvnet

    capture = capture_for(tset.rig, ctx.settings.storage_dir)
    frames = [f.frame for f in tset.frames]

    min_steps = config.handsegnet.round_min_steps if net == "handsegnet" else None

    def progress(p: Any) -> None:
        reporter(p.fraction, round_progress.train_message(net, p.step, p.seconds, budget, min_steps, p.loss))

    init_from = warm_start_of(ctx, net, config, int(extra["round_index"]))
    if init_from is not None:
        log.info("%s of round %s starts from %s", net, extra["round_index"], init_from)
    common = {"resume": True, "progress": progress, "seed": seed, "max_steps": round_max_steps(ctx.settings, net),
              "extra_metadata": extra, "checkpoint_every_s": 30.0, "init_from": init_from}
    if net == "handsegnet":
        dataset = build_handseg_dataset(capture, frames, hand_masks=masks)
        return train_handsegnet(dataset, config, budget, folder, min_steps=min_steps, **common)
    detections, offsets = None, None
    if config.mvnet.heatmap_source == "detector":
        reporter(0.0, f"{net}: detecting keypoints in {len(frames)} samples (cached per frame)", force=True)
        detections = training_detections(ctx, frames, list(tset.rig.cameras), masks)
    if config.mvnet.detector_offsets and detections is not None:
        offsets = learn_detector_offsets(detections, tset.keypoints_3d, pose=config.mvnet.detector_pose_correction)
        common["extra_metadata"] = {**extra, "detector_offsets": offsets.summary()}
    dataset = build_mvnet_dataset(capture, frames, config.mvnet, keypoints_3d=tset.keypoints_3d, hand_masks=masks,
                                  detections=detections, detector_offsets=offsets)
    return train_mvnet(dataset, config, budget, folder, **common)


def round_max_steps(settings: Settings, net: str) -> int | None:
    """The step cap of `net`'s round training: HandSegNet's own where one is set, else the one of every network."""
    if net == "handsegnet" and settings.round_handsegnet_max_steps is not None:
        return int(settings.round_handsegnet_max_steps)
    return settings.round_max_train_steps


def training_detections(ctx: WorkerContext, frames: list[Any], cameras: list[Any],
                        masks: list[dict[str, np.ndarray]] | None) -> list[Any]:
    """The detector on each training frame, inside its chroma-key masks where it has some, else inside the labels'
    model masks; through the rounds' detection cache (keyed by the masks too)."""
    cache = detection_cache(ctx)
    out = []
    for i, frame in enumerate(frames):
        chroma = chroma_masks(frame, cameras)
        given = masks[i] if masks is not None else None
        if chroma is not None or given is None:
            out += detect_frames([frame], cameras, handedness=ROUND_HANDEDNESS, cache=cache)
            continue
        ordered = [np.asarray(given[c.name], bool) if c.name in given else None for c in cameras]
        digest = hashlib.sha1(b"".join(np.packbits(m).tobytes() for m in ordered if m is not None)).hexdigest()[:12]
        out += detect_frames([frame], cameras, handedness=ROUND_HANDEDNESS, masks=lambda _f, o=ordered: o,
                             masks_label=f"labels-{digest}", cache=cache)
    return out


def reuse_checkpoint(ctx: WorkerContext, version: str) -> dict[str, Any]:
    """Metadata of an existing version (for a round launched with given model versions)."""
    path = checkpoint_of(ctx, version)
    sidecar = path.with_suffix(".json")
    if not path.is_file() or not sidecar.is_file():
        raise InputError(f"model version {version!r}: no checkpoint at {path}")
    return json.loads(sidecar.read_text())


def fail_with_round(ctx: WorkerContext, job_id: int, round_job_id: int | None, message: str) -> None:
    with ctx.session_factory.begin() as session:
        jobs.finish(session, job_id, JobState.failed, error=message[:2000])
        if round_job_id is not None:
            jobs.finish(session, int(round_job_id), JobState.failed, error=message[:2000])

