"""`handloop bench realrig`: a lab's first hour on the real two-webcam recording (../shared/realdata/handpose3d)."""

from __future__ import annotations

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("realrig")
    def bench_realrig(
        json_out: bool = typer.Option(False, "--json", help="Print the JSON record as the last stdout line."),
        quick: bool = typer.Option(False, "--quick", help="Every 30th frame (13 frames) instead of every 5th (76)."),
        every: int | None = typer.Option(None, "--every", min=1, max=378, help="Keep every n-th frame."),
    ) -> None:
        """Convert the recording's board-unit calibration as read, find its scale from the hand, convert it again
        at that scale, and pre-annotate every frame; report the figures against the issue's targets."""
        from backend.bench.realdata import RealDataMissingError
        from backend.bench.realrig import run

        try:
            record = run(quick=quick, every=every, emit_json=json_out)
        except (RuntimeError, RealDataMissingError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
        if not json_out:
            typer.echo(f"scale factor {record['scale_factor']} m per board square (reference "
                       f"{record['reference_factor']}); {record['fitted']} of {record['frames']} frames fitted; "
                       f"epipolar {record['epipolar_median_px']} px median; fit residual "
                       f"{record['fit_residual_median_px']} px median")
