"""Benchmark of bringing a real-sized capture in: `handloop capture assemble` from per-camera folders of
2048x1536 JPEGs, then `handloop import` (reader checks, rows, copies into storage).

Full run: 8 cameras x 100 frames; --quick: 8 cameras x 24 frames. The source JPEGs are generated first
(textured, shifted per frame, quality 90; not timed) in a temporary folder removed afterwards. With
`videos`, the sources are one MJPG .avi per camera instead: every frame is decoded and re-encoded.
Memory: the proportional set size (PSS) of this process and all its descendants (worker processes
included), sampled every 100 ms from /proc; `memory_vs_frames` is the peak reached by the time 25 / 50 /
75 / 100 % of the frames were assembled (flat when memory does not grow with the number of frames).
"""

from __future__ import annotations

import logging
import os
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from backend.bench.common import emit
from backend.bench.import_ui import measure
from backend.db.migrate import upgrade
from backend.db.session import create_engine_from_url, make_session_factory
from backend.services.captures.importer import import_capture
from backend.services.captures.storage import LocalDiskStorage
from workers.capture import read_capture
from workers.capture.assemble import assemble_capture
from workers.geometry.rig import default_rig

log = logging.getLogger(__name__)

WIDTH, HEIGHT = 2048, 1536
SOURCE_JPEG_QUALITY = 90
# quick -> (cameras, frames)
SIZES: dict[bool, tuple[int, int]] = {True: (8, 24), False: (8, 100)}


def _pss_bytes(pid: int) -> int:
    """Proportional set size: resident pages, shared ones divided among their sharers (forked workers share
    the parent's pages, which a sum of RSS would count once per worker)."""
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            for line in f:
                if line.startswith("Pss:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0


def _children(pid: int) -> list[int]:
    out = []
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/children") as f:
                out.extend(int(v) for v in f.read().split())
    except (OSError, ValueError):
        pass
    return out


def _descendants(root: int) -> list[int]:
    out, todo = [], [root]
    while todo:
        pid = todo.pop()
        out.append(pid)
        todo.extend(_children(pid))
    return out


class TreeMemory:
    """Samples the resident memory of this process and its descendants in a thread; `peak` in bytes."""

    def __init__(self, interval_s: float = 0.1) -> None:
        self.interval_s = interval_s
        self.peak = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def sample(self) -> None:
        self.peak = max(self.peak, sum(_pss_bytes(p) for p in _descendants(os.getpid())))

    def _run(self) -> None:
        while not self._stop.wait(self.interval_s):
            self.sample()

    def __enter__(self) -> TreeMemory:
        self.sample()  # here, not only in the thread: a short phase may end before the thread first runs
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.sample()


def bench_rig(cameras: int) -> list[Any]:
    """`cameras` cameras of the default rig's geometry, all 2048x1536 (the issue's image size)."""


    rig = []
    for cam in default_rig(WIDTH)[:cameras]:
        K = cam.K.copy()
        K[1, 2] += (HEIGHT - cam.height) / 2  # same principal point relative to the centre
        rig.append(replace(cam, height=HEIGHT, K=K))
    return rig


def write_sources(folder: Path, cameras: list[Any], frames: int, progress: Any = None) -> int:
    """Per camera a folder of `frames` textured JPEGs; returns the bytes written."""

    rng = np.random.default_rng(0)
    small = rng.integers(0, 256, (HEIGHT // 16, WIDTH // 16, 3), dtype=np.uint8)
    base = cv2.resize(small, (WIDTH, HEIGHT), interpolation=cv2.INTER_CUBIC)
    base = cv2.add(base, rng.integers(0, 24, (HEIGHT, WIDTH, 3), dtype=np.uint8))  # sensor-like grain

    def one(job: tuple[int, int]) -> int:
        c, i = job
        image = np.roll(base, (7 * i + 50 * c, 11 * i), axis=(0, 1))
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, SOURCE_JPEG_QUALITY])
        if not ok:
            raise RuntimeError("OpenCV could not encode a benchmark JPEG")
        path = folder / cameras[c].name / f"img_{i:05d}.jpg"
        path.write_bytes(data.tobytes())
        if progress is not None:
            progress(1)
        return len(data)

    for cam in cameras:
        (folder / cam.name).mkdir(parents=True, exist_ok=True)
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        return sum(pool.map(one, [(c, i) for c in range(len(cameras)) for i in range(frames)]))


def write_videos(folder: Path, cameras: list[Any], frames: int, progress: Any = None) -> int:
    """Per camera an MJPG .avi of `frames` textured frames (OpenCV's own codec, no FFmpeg needed to read it
    back); returns the bytes written."""

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    base = cv2.resize(rng.integers(0, 256, (HEIGHT // 16, WIDTH // 16, 3), dtype=np.uint8), (WIDTH, HEIGHT),
                      interpolation=cv2.INTER_CUBIC)

    def one(c: int) -> int:
        path = folder / f"{cameras[c].name}.avi"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (WIDTH, HEIGHT))
        if not writer.isOpened():
            raise RuntimeError("OpenCV cannot write MJPG videos here")
        for i in range(frames):
            writer.write(np.roll(base, (7 * i + 50 * c, 11 * i), axis=(0, 1)))
            if progress is not None:
                progress(1)
        writer.release()
        return path.stat().st_size

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        return sum(pool.map(one, range(len(cameras))))


def run(*, quick: bool = False, workers: int = 0, videos: bool = False, emit_json: bool = True,
        ui: bool = True, ui_repeats: int = 3, working_width: int | None = None) -> dict[str, Any]:
    """Run the benchmark and return its record (printed as the last stdout line when `emit_json`).

    `ui`: then measure the annotate page's time to interactive on the imported project in headless Chromium
    (backend.bench.import_ui; `ui_repeats` loads). `working_width`: the capture's working width (default
    assemble's own)."""


    started = time.perf_counter()
    num_cameras, frames = SIZES[quick]
    cameras = bench_rig(num_cameras)
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="handloop-bench-import-") as tmp_dir:
        tmp = Path(tmp_dir)
        with tqdm(total=num_cameras * frames, unit="image", desc="bench import: sources", file=sys.stderr) as bar:
            write = write_videos if videos else write_sources
            source_bytes = write(tmp / "sources", cameras, frames, bar.update)

        checkpoints = [round(frames * num_cameras * q) for q in (0.25, 0.5, 0.75, 1.0)]
        memory_vs_frames: list[dict[str, Any]] = []
        done = 0
        with TreeMemory() as memory, tqdm(total=num_cameras * frames, unit="image", desc="bench import: assemble",
                                          file=sys.stderr) as bar:
            def progress(n: int) -> None:
                nonlocal done
                done += n
                bar.update(n)
                while checkpoints and done >= checkpoints[0]:
                    memory_vs_frames.append({"frames": checkpoints.pop(0) // num_cameras,
                                             "peak_pss_mb": round(memory.peak / 2**20, 1)})

            t0 = time.perf_counter()
            source = {"videos": tmp / "sources"} if videos else {"images": tmp / "sources"}
            assemble_capture(cameras, tmp / "capture", **source, workers=workers, progress=progress,
                             working_width_px=working_width)
            assemble_s = time.perf_counter() - t0
            assemble_peak = memory.peak

        database = tmp / "bench.sqlite"
        url = f"sqlite:///{database}"
        upgrade(url)
        engine = create_engine_from_url(url)
        try:
            print("bench import: importing", file=sys.stderr, flush=True)
            with TreeMemory() as memory:
                t0 = time.perf_counter()
                with make_session_factory(engine).begin() as session:
                    result = import_capture(session, LocalDiskStorage(tmp / "storage"), tmp / "capture",
                                            project_name="bench")
                import_s = time.perf_counter() - t0
                import_peak = memory.peak
        finally:
            engine.dispose()
        load_after = os.getloadavg()
        annotate_page: dict[str, Any] | None = None
        if ui:
            width = read_capture(tmp / "capture", check_images=False).working_width_px
            annotate_page = measure(url, tmp / "storage", "bench", working_width=width, repeats=ui_repeats)
    record = {
        "end_to_end_frames_per_s": round(frames / (assemble_s + import_s), 3),
        "assemble_frames_per_s": round(frames / assemble_s, 3),
        "import_frames_per_s": round(frames / import_s, 3),
        "assemble_s": round(assemble_s, 3),
        "import_s": round(import_s, 3),
        "frames": frames,
        "cameras": num_cameras,
        "image_px": [WIDTH, HEIGHT],
        "source_mb": round(source_bytes / 2**20, 1),
        "assemble_peak_pss_mb": round(assemble_peak / 2**20, 1),
        "import_peak_pss_mb": round(import_peak / 2**20, 1),
        "memory_vs_frames": memory_vs_frames,
        "views_imported": result.views,
        "target_frames_per_s": 10.0,
        "annotate_interactive_ms": None if annotate_page is None else annotate_page["interactive_ms"],
        "annotate_page": annotate_page,
        "target_annotate_interactive_ms": 1000.0,
        "load_average": {"before": [round(v, 2) for v in load_before], "after": [round(v, 2) for v in load_after]},
    }
    settings = {"quick": quick, "source": "mjpg videos" if videos else "jpeg folders",
                "workers": workers or min(num_cameras, os.cpu_count() or 1),
                "source_jpeg_quality": SOURCE_JPEG_QUALITY, "ui": ui, "ui_repeats": ui_repeats,
                "working_width_px": working_width}
    return emit("import", record, settings, started) if emit_json else record
