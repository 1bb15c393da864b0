"""`handloop bench import`: assembling and importing 8 cameras x 100 frames of 2048x1536 JPEGs."""

from __future__ import annotations

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("import")
    def bench_import(
        json_out: bool = typer.Option(False, "--json", help="Print the JSON record as the last stdout line."),
        quick: bool = typer.Option(False, "--quick", help="Reduced run: 24 frames instead of 100."),
        workers: int = typer.Option(0, min=0, max=256, help="Assembly processes (0 = one per CPU core)."),
        videos: bool = typer.Option(False, "--videos", help="Sources as one MJPG video per camera (decoded and "
                                                            "re-encoded) instead of JPEG folders (copied)."),
    ) -> None:
        """Time `capture assemble` + `import` of real-sized JPEGs (frames/s, peak memory, memory vs frames)."""
        from backend.bench.capture_import import run

        record = run(quick=quick, workers=workers, videos=videos, emit_json=json_out)
        if not json_out:
            typer.echo(f"{record['end_to_end_frames_per_s']:.2f} eight-view frames/s end to end (assemble "
                       f"{record['assemble_frames_per_s']:.2f}, import {record['import_frames_per_s']:.2f}); peak "
                       f"{record['assemble_peak_pss_mb']:.0f} MB assembling, {record['import_peak_pss_mb']:.0f} MB "
                       f"importing; {record['frames']} frames x {record['cameras']} cameras")
