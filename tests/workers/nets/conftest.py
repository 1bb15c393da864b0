"""A tiny synthetic capture shared by the network tests (2 training sequences x 1 frame, 128 px), and one
torch thread (the machine is shared: more threads than free cores slow training several-fold)."""

from __future__ import annotations

import pytest

from workers.capture.reader import read_capture
from workers.capture.schema import Capture


@pytest.fixture(scope="session")
def tiny_capture(tmp_path_factory) -> Capture:
    from workers.synth.generator import generate_capture
    from workers.synth.plan import SynthConfig

    out = tmp_path_factory.mktemp("nets_capture")
    generate_capture(out, SynthConfig(num_sequences=2, frames_per_sequence=1, seed=3, width_px=128), workers=1,
                     force=True)
    return read_capture(out)


@pytest.fixture(scope="session")
def tiny_frames(tiny_capture):
    return [f for s in tiny_capture.sequences for f in s.frames]


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread():
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)
