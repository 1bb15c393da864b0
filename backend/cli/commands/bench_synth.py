"""`handloop bench synth`: synthetic-capture rendering speed (frames of all views per second)."""

from __future__ import annotations

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("synth")
    def bench_synth(
        json_out: bool = typer.Option(False, "--json", help="Print the JSON record as the last stdout line."),
        quick: bool = typer.Option(False, "--quick", help="Reduced run (about a minute or less)."),
        width: int | None = typer.Option(None, min=32, max=4096, help="Image width (default: settings)."),
        workers: int = typer.Option(0, min=0, max=256, help="Processes (0 = one per CPU core)."),
    ) -> None:
        """Time `handloop synth` end to end (rendering, encoding and writing) into a temporary folder."""
        from backend.bench.synth import run

        record = run(quick=quick, width_px=width, workers=workers, emit_json=json_out)
        if not json_out:
            typer.echo(f"{record['frames_per_s']:.2f} frames/s ({record['ms_per_frame']:.0f} ms per 8-view frame, "
                       f"{record['frames']} frames at {record['settings']['width_px']} px)")
