"""`handloop bench fit`: accuracy and speed of the fitting engine on synthetic frames."""

from __future__ import annotations

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("fit")
    def bench_fit(
        json_out: bool = typer.Option(False, "--json", help="Print the JSON record as the last stdout line."),
        quick: bool = typer.Option(False, "--quick", help="Reduced run (about a minute)."),
        frames_per_sequence: int | None = typer.Option(
            None, "--frames-per-sequence", min=1, max=1000,
            help="Frames of each of the 3 sequences fitted (default 10, i.e. 30 frames; 3 with --quick)."),
    ) -> None:
        """Fit synthetic frames (clicks with noise 0/2/5 px; ground-truth or chroma-key masks; with and
        without silhouettes) and report errors against ground truth and seconds per frame."""
        from backend.bench.fit import run

        record = run(quick=quick, emit_json=json_out, frames_per_sequence=frames_per_sequence)
        if not json_out:
            for row in record["rows"]:
                typer.echo(f"sigma {row['sigma_px']:.0f} px  {row['masks']:<12}  silhouette {row['silhouette']!s:<5}  "
                           f"vertex {row['vertex_mm']:6.2f} mm  keypoints {row['keypoint_mm']:6.2f} mm  "
                           f"median {row['median_s_per_frame']:.2f} s")
