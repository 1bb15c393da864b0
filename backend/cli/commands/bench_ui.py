"""`handloop bench ui`: the browser UI's speed in a real browser (backend/bench/ui.py)."""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import typer

CHROMIUM = "/usr/bin/chromium"


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("ui")
    def bench_ui(
        json_out: bool = typer.Option(False, "--json", help="Print only the JSON line on stdout."),
        quick: bool = typer.Option(False, "--quick", help="Fewer frames and repeats (about a minute)."),
        width: int = typer.Option(1280, min=320, max=4096, help="Image width of the synthetic capture."),
        frames: int = typer.Option(13, min=7, max=200, help="Frames (samples) in the capture."),
        repeats: int = typer.Option(3, min=1, max=50, help="Cold page loads per page."),
        brush_events: int = typer.Option(300, min=10, max=100_000, help="Pointer events in the brush test."),
        scripted: int = typer.Option(3, min=1, max=50, help="Samples per scripted-annotator run (T, M)."),
        chromium: str = typer.Option(CHROMIUM, help="Chromium executable."),
    ) -> None:
        """Page interactive, next sample after a decision, brush event handling: in a real browser."""
        from backend.bench.common import emit
        from backend.bench.ui import CHROMIUM_ARGS, run

        if quick:
            frames, repeats, brush_events, scripted = min(frames, 7), 1, min(brush_events, 150), min(scripted, 1)
        if not Path(chromium).exists():
            raise typer.BadParameter(f"Chromium not found at {chromium} (apt-get install -y chromium)",
                                     param_hint="--chromium")
        started = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix="handloop-bench-ui-") as tmp:
            result = run(Path(tmp), width=width, frames=frames, repeats=repeats, brush_events=brush_events,
                         chromium=chromium, scripted=scripted)
        emit("ui", result, {"width": width, "frames": frames, "repeats": repeats, "brush_events": brush_events,
                            "scripted_samples": scripted,
                            "chromium": chromium, "chromium_args": CHROMIUM_ARGS, "quick": quick,
                            "load_average": [round(v, 2) for v in os.getloadavg()]}, started)
        del json_out  # the JSON line is always the last stdout line; progress goes to stderr
