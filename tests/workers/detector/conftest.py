"""Shared fixtures: a small rendered capture with ground truth (`require_detector` is tests/conftest.py's)."""

from __future__ import annotations

from pathlib import Path

import pytest

RENDER_SEED = 31


@pytest.fixture(scope="session")
def rendered_capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One green-screen sequence of 2 frames at 320 px (the built-in hand; chroma-key masks and ground truth)."""
    from workers.synth.generator import generate_capture
    from workers.synth.plan import SynthConfig

    out = tmp_path_factory.mktemp("detector") / "capture"
    generate_capture(out, SynthConfig(num_sequences=1, frames_per_sequence=2, seed=RENDER_SEED, width_px=320))
    return out


@pytest.fixture(scope="session")
def rendered_left_capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same with a left hand: one green-screen frame at 320 px."""
    from workers.synth.generator import generate_capture
    from workers.synth.plan import SynthConfig

    out = tmp_path_factory.mktemp("detector-left") / "capture"
    generate_capture(out, SynthConfig(num_sequences=1, frames_per_sequence=1, seed=RENDER_SEED, width_px=320,
                                      side="left"))
    return out
