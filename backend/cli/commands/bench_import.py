"""`handloop bench import`: assembling and importing 8 cameras x 100 frames of 2048x1536 JPEGs."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("import")
    def bench_import(
        json_out: bool = typer.Option(False, "--json", help="Print the JSON record as the last stdout line."),
        quick: bool = typer.Option(False, "--quick", help="Reduced run: 24 frames instead of 100."),
        workers: int = typer.Option(0, min=0, max=256, help="Assembly processes (0 = one per CPU core)."),
        videos: bool = typer.Option(False, "--videos", help="Sources as one MJPG video per camera (decoded and "
                                                            "re-encoded) instead of JPEG folders (copied)."),
        ui: bool = typer.Option(True, "--ui/--no-ui", help="Also the annotate page's time to interactive on the "
                                "imported capture (headless Chromium at /usr/bin/chromium, Playwright)."),
        ui_repeats: int = typer.Option(3, min=1, max=50, help="Cold annotate page loads per measurement."),
        working_width: int | None = typer.Option(None, "--working-width", min=16, max=100_000,
                                                 help="The capture's working width (default: assemble's)."),
    ) -> None:
        """Time `capture assemble` + `import` of real-sized JPEGs (frames/s, peak memory, memory vs frames)."""
        from backend.bench.capture_import import run
        from backend.bench.import_ui import CHROMIUM

        if ui and not Path(CHROMIUM).exists():
            raise typer.BadParameter(f"Chromium not found at {CHROMIUM} (apt-get install -y chromium), or pass --no-ui")
        record = run(quick=quick, workers=workers, videos=videos, emit_json=json_out, ui=ui, ui_repeats=ui_repeats,
                     working_width=working_width)
        if not json_out:
            typer.echo(f"{record['end_to_end_frames_per_s']:.2f} eight-view frames/s end to end (assemble "
                       f"{record['assemble_frames_per_s']:.2f}, import {record['import_frames_per_s']:.2f}); peak "
                       f"{record['assemble_peak_pss_mb']:.0f} MB assembling, {record['import_peak_pss_mb']:.0f} MB "
                       f"importing; {record['frames']} frames x {record['cameras']} cameras")
            if record["annotate_interactive_ms"] is not None:
                typer.echo(f"annotate page interactive in {record['annotate_interactive_ms']:.0f} ms (target 1000)")
