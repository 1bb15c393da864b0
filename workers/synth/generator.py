"""Write a synthetic capture: plan, then render frames in a process pool and write them as they come.

Each worker process builds the hand model, the torch layer and the per-sequence look once, then renders
chunks of consecutive frames. Every random choice derives from the seed, the sequence and the frame
index, so the capture is the same for any number of workers.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_all_start_methods, get_context
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from workers.capture.schema import CAPTURE_FILE, HandModelInfo
from workers.capture.writer import write_capture_header, write_frame, write_sequence
from workers.geometry.rig import default_rig
from workers.handmodel import HandLayer, load_hand_model
from workers.handmodel.pose_sampler import sampler_for
from workers.synth.compositing import NoiseBank, hex_to_srgb, srgb_to_linear
from workers.synth.frame import HandState, SequenceLook, render_frame, sequence_backgrounds, sequence_lighting
from workers.synth.motion import evaluate, hand_axes, plan_motion
from workers.synth.plan import SequencePlan, SynthConfig, plan_capture
from workers.synth.subjects import skin_albedo

log = logging.getLogger(__name__)

CHUNK_FRAMES = 4  # frames per task: small enough for a smooth progress bar, big enough to batch the layer


class SynthError(ValueError):
    """Bad arguments or output folder for synthesis; the message says what to change."""


@dataclass(frozen=True)
class SynthResult:
    """What `generate_capture` wrote and how long it took.

    Attributes:
        root: the capture folder.
        num_frames: multi-view frames written (all sequences).
        num_views: images per frame.
        seconds: wall-clock time of the whole run (pool start-up included).
        render_seconds: wall-clock time from the first task submitted to the last frame written.
    """

    root: Path
    num_frames: int
    num_views: int
    seconds: float
    render_seconds: float

    @property
    def frames_per_s(self) -> float:
        return self.num_frames / self.seconds if self.seconds > 0 else math.inf


def prepare_output(out_dir: Path, force: bool) -> None:
    """Refuse a non-empty folder unless `force`; with `force`, only an earlier capture is replaced."""
    if out_dir.exists() and not out_dir.is_dir():
        raise SynthError(f"{out_dir}: exists and is not a folder")
    if out_dir.is_dir() and any(out_dir.iterdir()):
        if not force:
            raise SynthError(f"{out_dir}: folder is not empty; pass --force to replace an earlier capture")
        if not (out_dir / CAPTURE_FILE).is_file():
            raise SynthError(f"{out_dir}: not empty and holds no {CAPTURE_FILE}; refusing to delete it even with "
                             "--force (choose an empty or new folder)")
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)


# --- worker side -----------------------------------------------------------------------------------


class FrameRenderer:
    """Renders frames of a planned capture: hand model, layer, cameras, plans and per-sequence caches.

    One per process; `render` is deterministic for a given (config, sequence, frame).
    """

    def __init__(self, config: SynthConfig, out_dir: Path | None = None, mano_path: Path | None = None) -> None:
        self.config = config
        self.out_dir = out_dir
        self.arrays = load_hand_model(mano_path, config.side)
        self.layer = HandLayer(self.arrays, dtype=torch.float64)
        self.cameras = tuple(default_rig(config.width_px, seed=config.rig_seed))
        self.plans = plan_capture(config)[1]
        self.sequences: dict[int, tuple[Any, Any, np.ndarray]] = {}
        self.noise = NoiseBank(sigma=0.01, seed=config.seed)

    def _forward(self, betas: np.ndarray, pose: np.ndarray, orient: np.ndarray, transl: np.ndarray) -> Any:
        with torch.no_grad():
            t = lambda a: torch.as_tensor(np.asarray(a, np.float64))  # noqa: E731
            return self.layer(t(betas), t(pose), t(orient), t(transl))

    def _sequence(self, index: int) -> tuple[Any, Any, np.ndarray]:
        """(look, motion plan, rest wrist joint) of a sequence, built once per process."""
        if index in self.sequences:
            return self.sequences[index]

        plan: SequencePlan = self.plans[index]
        betas = plan.subject.betas[None]
        rest = self._forward(betas, np.zeros((1, 45)), np.zeros((1, 3)), np.zeros((1, 3)))
        rest_axes = hand_axes(rest.keypoints[0].numpy(), self.config.side)
        rng = np.random.default_rng([plan.seed, 2])
        sampler = sampler_for(self.arrays)
        n_keys = self.config.frames_per_sequence // 6 + 3
        if plan.held_object is None:
            key_poses = sampler.sample(n_keys, rng)
        else:
            grasp = {"ball": "sphere_grasp", "cylinder": "cylinder_grasp", "box": "disc_grasp"}[plan.held_object.kind]
            base = sampler.canonical_poses()[grasp]
            w = rng.uniform(0.0, 0.25, (n_keys, 1))
            key_poses = (1 - w) * base[None] + w * sampler.sample(n_keys, rng)
        motion = plan_motion(rng, self.config.frames_per_sequence, key_poses, rest_axes)
        tone = plan.subject.skin_tone or "#d7bd96"
        look = SequenceLook(
            plan=plan, cameras=self.cameras, backgrounds=sequence_backgrounds(plan, self.cameras),
            shading=sequence_lighting(plan.green_screen, np.random.default_rng([plan.seed, 3])),
            hand_albedo=skin_albedo(tone, self.arrays.v_template, np.random.default_rng([plan.seed, 4])),
            skin_rgb=srgb_to_linear(hex_to_srgb(tone)), spill=0.4 if plan.green_screen else 0.0,
            spill_width_px=max(0.5, 1.2 * self.config.width_px / 320),
            noise=self.noise, side=self.config.side,
        )
        self.sequences[index] = (look, motion, rest.joints[0, 0].numpy())
        return self.sequences[index]

    def render(self, index: int, start: int, stop: int) -> list[Any]:
        """Frames start..stop-1 of sequence `index` as `RenderedFrame`s (nothing is written)."""

        look, motion, rest_wrist = self._sequence(index)
        plan = look.plan
        frames = np.arange(start, stop)
        sample = evaluate(motion, frames)
        T = len(frames)
        betas = np.repeat(plan.subject.betas[None], T, axis=0)
        transl = sample.wrist_m - rest_wrist[None]
        posed = self._forward(betas, sample.pose, sample.global_orient, transl)
        verts, keypoints = posed.vertices.numpy(), posed.keypoints.numpy()
        faces = self.arrays.faces
        out = []
        for k, f in enumerate(frames):
            hand = HandState(betas=betas[k], pose=sample.pose[k], global_orient=sample.global_orient[k],
                             transl=transl[k], vertices=verts[k], keypoints=keypoints[k],
                             forearm_axis=sample.forearm_axis[k])
            out.append(render_frame(look, hand, faces, np.random.default_rng([plan.seed, 5, int(f)])))
        return out

    def render_chunk(self, index: int, start: int, stop: int) -> int:
        """Render and write frames start..stop-1 of sequence `index`; returns how many."""
        plan = self.plans[index]
        for f, rendered in zip(range(start, stop), self.render(index, start, stop), strict=True):
            write_frame(self.out_dir, plan.id, f, rendered.images, masks=rendered.chroma_masks,
                        ground_truth=rendered.ground_truth)
        return stop - start


_WORKER: FrameRenderer | None = None


def _single_threaded() -> None:
    """One process per core: keep torch and OpenCV from starting thread pools of their own."""
    torch.set_num_threads(1)
    cv2.setNumThreads(1)


def _init_worker(config: SynthConfig, out_dir: Path, mano_path: Path | None) -> None:
    """Pool initializer: build the worker state unless it was inherited through fork."""
    global _WORKER
    _single_threaded()
    if _WORKER is None or _WORKER.config != config or _WORKER.out_dir != out_dir:
        _WORKER = FrameRenderer(config, out_dir, mano_path)


def _run_chunk(index: int, start: int, stop: int) -> int:
    assert _WORKER is not None, "worker not initialised"
    return _WORKER.render_chunk(index, start, stop)


# --- driver ----------------------------------------------------------------------------------------


def generate_capture(out_dir: Path, config: SynthConfig, *, workers: int = 0, force: bool = False,
                     mano_path: Path | None = None, progress: Callable[[int], None] | None = None,
                     name: str | None = None) -> SynthResult:
    """Synthesise a capture into `out_dir`.

    Args:
        out_dir: output folder: new, empty, or (with `force`) an earlier capture to replace.
        config: what to synthesise.
        workers: processes; 0 = one per CPU core (at most the number of tasks); 1 = in this process.
        force: replace an earlier capture in `out_dir`.
        mano_path: the user's MANO file or folder; None = the built-in hand.
        progress: called with the number of frames finished, as they finish.
        name: the capture's name (default: the folder name).
    Returns:
        What was written and how long it took.
    """
    started = time.perf_counter()
    out_dir = Path(out_dir)
    prepare_output(out_dir, force)
    arrays = load_hand_model(mano_path, config.side)
    cameras = default_rig(config.width_px, seed=config.rig_seed)
    subjects, plans = plan_capture(config)
    info = HandModelInfo(name=arrays.name, is_mano=arrays.is_mano, side=arrays.side,
                         num_vertices=arrays.num_vertices, source_note=arrays.source_note)
    write_capture_header(out_dir, name or out_dir.resolve().name, cameras, subjects, info, synthetic=True,
                         description="Synthetic capture written by `handloop synth`.",
                         generator={"tool": "handloop synth", "seed": config.seed, "width_px": config.width_px,
                                    "sequences": config.num_sequences, "frames": config.frames_per_sequence})
    for plan in plans:
        write_sequence(out_dir, plan.id, subject_id=plan.subject.id, split=plan.split,
                       green_screen=plan.green_screen, fps=config.fps, num_frames=config.frames_per_sequence,
                       holds_object=plan.held_object is not None, camera_names=[c.name for c in cameras],
                       object_kind=plan.held_object.kind if plan.held_object else None,
                       background="green screen" if plan.green_screen else plan.background,
                       with_masks=plan.green_screen, with_ground_truth=True)
    tasks = [(p.index, s, min(s + CHUNK_FRAMES, config.frames_per_sequence))
             for p in plans for s in range(0, config.frames_per_sequence, CHUNK_FRAMES)]
    workers = workers or (os.cpu_count() or 1)
    workers = max(1, min(workers, len(tasks)))
    log.info("synthesising %d sequences x %d frames x %d views at %d px with %d worker(s)",
             config.num_sequences, config.frames_per_sequence, len(cameras), config.width_px, workers)
    global _WORKER
    threads = (torch.get_num_threads(), cv2.getNumThreads())
    _single_threaded()  # restored below; torch's spinning OpenMP threads only hurt on small tensors
    try:
        # Built here, before the pool: forked workers inherit it (torch imported, model loaded, no start-up
        # cost); the parent only constructs tensors and never runs a parallel torch op, so forking is safe.
        _WORKER = FrameRenderer(config, out_dir, mano_path)
        render_started = time.perf_counter()
        done = 0
        if workers == 1:
            for task in tasks:
                n = _WORKER.render_chunk(*task)
                done += n
                if progress:
                    progress(n)
        else:
            method = "fork" if "fork" in get_all_start_methods() else "spawn"
            with ProcessPoolExecutor(max_workers=workers, mp_context=get_context(method), initializer=_init_worker,
                                     initargs=(config, out_dir, mano_path)) as pool:
                futures = [pool.submit(_run_chunk, *task) for task in tasks]
                for future in as_completed(futures):
                    n = future.result()
                    done += n
                    if progress:
                        progress(n)
    finally:
        _WORKER = None
        torch.set_num_threads(threads[0])
        cv2.setNumThreads(threads[1])
    finished = time.perf_counter()
    return SynthResult(root=out_dir, num_frames=done, num_views=len(cameras), seconds=finished - started,
                       render_seconds=finished - render_started)
