"""`handloop bench detect`: the pretrained detector, its multi-view lift and fits from it, on synthetic frames."""

from __future__ import annotations

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("detect")
    def bench_detect(
        json_out: bool = typer.Option(False, "--json", help="Print the JSON record as the last stdout line."),
        quick: bool = typer.Option(False, "--quick", help="Reduced run (under a minute once the capture is cached)."),
        width: int | None = typer.Option(None, "--width", min=64, max=4096,
                                         help="Image width of the synthetic rig (default: the render width, 320)."),
        frames_per_sequence: int | None = typer.Option(
            None, "--frames-per-sequence", min=1, max=1000,
            help="Frames of each sequence (green-screen ones are used; default 6, 2 with --quick)."),
        seed: int | None = typer.Option(None, "--seed", min=0, help="The capture's seed (default 9015, which nothing "
                                        "is tuned on)."),
        sequences: int = typer.Option(4, "--sequences", min=1, max=100, help="Sequences of the capture (default 4)."),
    ) -> None:
        """Detect, lift and fit held-out synthetic frames; report 2D, 3D and vertex errors and seconds per frame."""
        from backend.bench.detect import BENCH_SEED, run

        try:
            record = run(quick=quick, emit_json=json_out, width=width, frames_per_sequence=frames_per_sequence,
                         seed=BENCH_SEED if seed is None else seed, sequences=sequences)
        except RuntimeError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
        if not json_out:
            typer.echo(f"2D {record['kp2d_median_px']:.2f} px median ({record['kp2d_median_frac']:.3f} of the hand "
                       f"box), detected {record['detection_rate']:.0%}; 3D {record['kp3d_median_mm']} mm median; "
                       f"fits {record['fit_vertex_median_mm']} mm median vertex; {record['s_per_frame']:.2f} s/frame")
            h = record["detector_heuristic"]
            typer.echo(f"detector's heuristic: accepted {h['accepted']} of {h['fits']} fits, {h['accepted_over_10mm']} "
                       f"over 10 mm, {h['accepted_over_8mm']} over 8 mm; accepted {h['accepted_vertex_mean_mm']} mm "
                       f"mean, the rest {h['rest_vertex_mean_mm']} mm")
