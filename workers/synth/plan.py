"""What a synthetic capture will contain, decided up front from the seed (cheap, deterministic).

Split rule (documented in docs/capture-format.md): with N sequences, the last max(1, round(N / 4))
sequences are evaluation sequences (varied backgrounds) when N >= 2, the others training sequences
(green screen); a single sequence is a training sequence. Every odd-numbered sequence (1, 3, ...) holds
an object. Subject i // 2 performs sequence i (each subject records up to two sequences).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from workers.capture.schema import Subject
from workers.synth.backgrounds import evaluation_background_names
from workers.synth.props import OBJECT_KINDS, ForearmStyle, HeldObject
from workers.synth.subjects import sample_subjects

DEFAULT_FPS = 15.0
# Object colours (linear albedo): red, blue, yellow, white, orange, purple, black, wood. No greens.
OBJECT_COLORS: tuple[tuple[float, float, float], ...] = (
    (0.55, 0.04, 0.03), (0.04, 0.12, 0.55), (0.7, 0.55, 0.03), (0.75, 0.75, 0.72), (0.8, 0.25, 0.02),
    (0.25, 0.05, 0.4), (0.03, 0.03, 0.035), (0.35, 0.18, 0.07),
)
SLEEVE_COLORS: tuple[tuple[float, float, float], ...] = (
    (0.02, 0.03, 0.12), (0.3, 0.02, 0.03), (0.4, 0.4, 0.42), (0.02, 0.02, 0.02), (0.5, 0.3, 0.1),
)


@dataclass(frozen=True)
class SynthConfig:
    """Settings of `handloop synth`.

    Attributes:
        num_sequences: sequences to write, >= 1.
        frames_per_sequence: frames per sequence, >= 1.
        seed: everything random derives from it (the capture is identical for any worker count).
        width_px: working image width; heights follow each camera's aspect ratio.
        fps: frame rate written to sequence.json (a label-rate subsample of a real recording).
        rig_seed: seed of `default_rig`'s small calibration jitter.
        side: hand side, "right" or "left".
    """

    num_sequences: int
    frames_per_sequence: int
    seed: int = 0
    width_px: int = 320
    fps: float = DEFAULT_FPS
    rig_seed: int = 0
    side: str = "right"

    def __post_init__(self) -> None:
        if self.num_sequences < 1 or self.frames_per_sequence < 1:
            raise ValueError("num_sequences and frames_per_sequence must be >= 1")
        if not 32 <= self.width_px <= 4096:
            raise ValueError(f"width_px must be in 32..4096, got {self.width_px}")
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"fps must be positive, got {self.fps}")
        if self.side not in ("right", "left"):
            raise ValueError(f"side must be 'right' or 'left', got {self.side!r}")


@dataclass(frozen=True)
class SequencePlan:
    """One sequence to synthesise.

    Attributes:
        index: position in the capture, 0-based.
        id: "seq000", ...
        subject: who performs it.
        split: "train" or "evaluation".
        background: "green_screen" or an evaluation background name (see backgrounds.py).
        held_object: the object, or None.
        forearm: forearm style.
        seed: seeds the sequence's motion, lighting, backgrounds and noise.
    """

    index: int
    id: str
    subject: Subject
    split: str
    background: str
    held_object: HeldObject | None
    forearm: ForearmStyle
    seed: int

    @property
    def green_screen(self) -> bool:
        return self.background == "green_screen"


def num_evaluation(num_sequences: int) -> int:
    """How many of N sequences are evaluation sequences: max(1, round(N / 4)) for N >= 2, else 0."""
    return 0 if num_sequences < 2 else max(1, round(num_sequences / 4))


def plan_capture(config: SynthConfig) -> tuple[list[Subject], list[SequencePlan]]:
    """Subjects and sequence plans for `config` (see the module docstring for the rules)."""
    rng = np.random.default_rng([config.seed, 0])
    n = config.num_sequences
    subjects = sample_subjects((n + 1) // 2, rng)
    n_eval = num_evaluation(n)
    backgrounds = list(evaluation_background_names())
    rng.shuffle(backgrounds)
    plans = []
    for i in range(n):
        evaluation = i >= n - n_eval
        obj = None
        if i % 2 == 1:
            kind = OBJECT_KINDS[int(rng.integers(len(OBJECT_KINDS)))]
            if kind == "ball":
                r = rng.uniform(0.032, 0.045)
                size = (r, r, r)
            elif kind == "cylinder":
                r = rng.uniform(0.022, 0.034)
                size = (r, r, rng.uniform(0.12, 0.22))
            else:
                size = (rng.uniform(0.02, 0.03), rng.uniform(0.05, 0.08), rng.uniform(0.1, 0.16))
            color = OBJECT_COLORS[int(rng.integers(len(OBJECT_COLORS)))]
            obj = HeldObject(kind=kind, size_m=tuple(float(s) for s in size), rgb=color)
        sleeve = None if rng.random() < 0.3 else float(rng.uniform(0.12, 0.3))
        forearm = ForearmStyle(growth=float(rng.uniform(0.25, 0.45)), sleeve_start_m=sleeve,
                               sleeve_rgb=SLEEVE_COLORS[int(rng.integers(len(SLEEVE_COLORS)))])
        plans.append(SequencePlan(
            index=i, id=f"seq{i:03d}", subject=subjects[i // 2],
            split="evaluation" if evaluation else "train",
            background=backgrounds[(i - (n - n_eval)) % len(backgrounds)] if evaluation else "green_screen",
            held_object=obj, forearm=forearm, seed=int(rng.integers(2**31)),
        ))
    return subjects, plans
