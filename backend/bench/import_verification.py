"""Benchmark of a capture's import, and what full verification of its files costs.

The capture is the demo's (`handloop demo`: 4 sequences x 12 frames, eight views at the default width),
synthesised into a temporary folder unless `capture` is given; `--quick`: 2 sequences x 6 frames. Each
repeat imports it into a fresh SQLite database and storage folder, timing the phases separately:
`read_s` (structure and image headers, `read_capture`), `verify_s` (every file decoded and checked,
`verify_capture_files`, in parallel threads), `write_s` (rows and copies, `importer.write_project`).
`before_s` = read + write (the import without full verification), `after_s` = read + verify + write (the
import now); `verify_one_thread_s` times the verification in one thread. Medians over the repeats.
"""

from __future__ import annotations

import logging
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from tqdm import tqdm

from backend.bench.common import emit
from backend.db.migrate import upgrade
from backend.db.session import create_engine_from_url, make_session_factory
from backend.services.captures.importer import write_project
from backend.services.captures.storage import LocalDiskStorage
from backend.settings import get_settings
from workers.capture import read_capture
from workers.capture.verify import count_files, verify_capture_files
from workers.synth.generator import generate_capture
from workers.synth.plan import SynthConfig

log = logging.getLogger(__name__)

# quick -> (sequences, frames per sequence)
SIZES: dict[bool, tuple[int, int]] = {True: (2, 6), False: (4, 12)}


def _import_once(capture_dir: Path, work: Path) -> dict[str, float]:
    work.mkdir(parents=True)
    url = f"sqlite:///{work / 'handloop.sqlite3'}"
    upgrade(url)
    engine = create_engine_from_url(url)
    try:
        times: dict[str, float] = {}
        started = time.perf_counter()
        capture = read_capture(capture_dir)
        times["read_s"] = time.perf_counter() - started
        started = time.perf_counter()
        verify_capture_files(capture)
        times["verify_s"] = time.perf_counter() - started
        started = time.perf_counter()
        verify_capture_files(capture, threads=1)
        times["verify_one_thread_s"] = time.perf_counter() - started
        started = time.perf_counter()
        with make_session_factory(engine).begin() as session:
            write_project(session, LocalDiskStorage(work / "storage"), capture, "bench")
        times["write_s"] = time.perf_counter() - started
        return times
    finally:
        engine.dispose()


def run(*, quick: bool = False, capture: Path | None = None, repeats: int = 3, width_px: int | None = None,
        emit_json: bool = True) -> dict[str, Any]:
    """Run the benchmark and return its record (printed as the last stdout line when `emit_json`)."""


    started = time.perf_counter()
    settings = get_settings()
    sequences, frames = SIZES[quick]
    width_px = width_px or settings.render_width_px
    given = capture
    with tempfile.TemporaryDirectory(prefix="handloop-bench-import-") as tmp:
        if capture is None:
            capture = Path(tmp) / "capture"
            config = SynthConfig(num_sequences=sequences, frames_per_sequence=frames, seed=0, width_px=width_px)
            with tqdm(total=sequences * frames, unit="frame", desc="synthesising", file=sys.stderr) as bar:
                generate_capture(capture, config, mano_path=settings.mano_path, progress=bar.update)
        files = count_files(read_capture(capture))
        size_mb = sum(p.stat().st_size for p in capture.rglob("*") if p.is_file()) / 1e6
        runs = []
        for i in tqdm(range(repeats), unit="import", desc="bench verify", file=sys.stderr):
            runs.append(_import_once(capture, Path(tmp) / f"run-{i}"))
    median = {key: statistics.median(r[key] for r in runs) for key in runs[0]}
    before = median["read_s"] + median["write_s"]
    after = before + median["verify_s"]
    record = {
        "before_s": round(before, 3),
        "after_s": round(after, 3),
        "verify_s": round(median["verify_s"], 3),
        "verify_one_thread_s": round(median["verify_one_thread_s"], 3),
        "read_s": round(median["read_s"], 3),
        "write_s": round(median["write_s"], 3),
        "verify_share": round(median["verify_s"] / after, 3),
        "files_verified": files,
        "capture_mb": round(size_mb, 1),
        "runs": [{k: round(v, 3) for k, v in r.items()} for r in runs],
        "load_average": os.getloadavg(),
    }
    bench_settings = {"quick": quick, "repeats": repeats, "threads": min(8, os.cpu_count() or 1),
                      "capture": str(given) if given else f"demo-sized: {sequences} x {frames} frames at {width_px} px"}
    if emit_json:
        return emit("import", record, bench_settings, started)
    return {**record, "settings": bench_settings}
