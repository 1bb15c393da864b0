"""Rendered synthetic frames shared by the synth tests (rendered once per session, in this process)."""

from __future__ import annotations

import pytest

from workers.synth.generator import FrameRenderer
from workers.synth.plan import SynthConfig

# Three sequences: seq000 train (no object), seq001 train holding an object, seq002 evaluation.
CONFIG = SynthConfig(num_sequences=3, frames_per_sequence=2, seed=1, width_px=160)


@pytest.fixture(scope="session")
def renderer() -> FrameRenderer:
    return FrameRenderer(CONFIG)


@pytest.fixture(scope="session")
def rendered(renderer: FrameRenderer) -> dict[int, list]:
    """sequence index -> its rendered frames (RenderedFrame)."""
    return {i: renderer.render(i, 0, CONFIG.frames_per_sequence) for i in range(CONFIG.num_sequences)}
