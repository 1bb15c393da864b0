"""Benchmark of `handloop synth`: eight-view frames per second, rendering, encoding and writing included.

Full run: 8 sequences x 40 frames (320 frames); --quick: 2 sequences x 30 frames (60 frames). Written
into a temporary folder that is removed afterwards. `frames_per_s` is end to end (pool start-up included);
`render_frames_per_s` starts the clock when the first task is submitted.
"""

from __future__ import annotations

import logging
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from tqdm import tqdm

from backend.bench.common import emit
from backend.settings import get_settings
from workers.synth.generator import generate_capture
from workers.synth.plan import SynthConfig

log = logging.getLogger(__name__)

# quick -> (sequences, frames per sequence)
SIZES: dict[bool, tuple[int, int]] = {True: (2, 30), False: (8, 40)}


def run(*, quick: bool = False, width_px: int | None = None, workers: int = 0, seed: int = 0,
        emit_json: bool = True) -> dict[str, Any]:
    """Run the benchmark and return its record (printed as the last stdout line when `emit_json`)."""



    started = time.perf_counter()
    settings = get_settings()
    sequences, frames = SIZES[quick]
    config = SynthConfig(num_sequences=sequences, frames_per_sequence=frames, seed=seed,
                         width_px=width_px or settings.render_width_px)
    with tempfile.TemporaryDirectory(prefix="handloop-bench-synth-") as tmp, \
            tqdm(total=sequences * frames, unit="frame", desc="bench synth", file=sys.stderr) as bar:
        result = generate_capture(Path(tmp) / "capture", config, workers=workers, mano_path=settings.mano_path,
                                  progress=bar.update)
    record = {
        "frames_per_s": round(result.frames_per_s, 3),
        "render_frames_per_s": round(result.num_frames / result.render_seconds, 3),
        "ms_per_frame": round(1000 * result.seconds / result.num_frames, 1),
        "frames": result.num_frames,
        "views_per_frame": result.num_views,
        "seconds": round(result.seconds, 3),
    }
    bench_settings = {"quick": quick, "sequences": sequences, "frames_per_sequence": frames,
                      "width_px": config.width_px, "workers": workers or os.cpu_count(), "seed": seed,
                      "hand_model": "mano" if settings.mano_path else "builtin"}
    if emit_json:
        return emit("synth", record, bench_settings, started)
    return {**record, "settings": bench_settings}
