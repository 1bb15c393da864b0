"""`handloop synth`: write a synthetic capture (docs/capture-format.md) with ground truth."""

from __future__ import annotations

import sys
from pathlib import Path

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @app.command("synth")
    def synth(
        out: Path = typer.Option(..., "--out", help="Output folder (new or empty; see --force)."),
        sequences: int = typer.Option(2, min=1, max=10_000, help="Number of sequences."),
        frames: int = typer.Option(10, min=1, max=100_000, help="Frames per sequence."),
        seed: int = typer.Option(0, min=0, help="Random seed: the same seed writes the same capture."),
        width: int | None = typer.Option(None, min=32, max=4096,
                                         help="Image width in pixels (default: HANDLOOP_RENDER_WIDTH_PX)."),
        workers: int = typer.Option(0, min=0, max=256, help="Processes (0 = one per CPU core)."),
        side: str = typer.Option("right", "--side", help="Which hand: right or left (ground truth from that "
                                 "side's hand model, recorded in capture.json's hand_model)."),
        force: bool = typer.Option(False, "--force", help="Replace an earlier capture in --out."),
    ) -> None:
        """Render synthetic multi-view sequences of a hand with ground truth.

        Training sequences are on a green screen (with chroma-key masks), evaluation sequences on
        varied backgrounds; with N >= 2 sequences the last max(1, round(N / 4)) are evaluation
        sequences, and every odd-numbered sequence holds an object.
        """
        from tqdm import tqdm

        from backend.settings import get_settings
        from workers.synth.generator import SynthError, generate_capture
        from workers.synth.plan import SynthConfig

        if side not in ("right", "left"):
            raise typer.BadParameter(f"--side must be right or left, not {side!r}")
        settings = get_settings()
        config = SynthConfig(num_sequences=sequences, frames_per_sequence=frames, seed=seed,
                             width_px=width or settings.render_width_px, side=side)
        with tqdm(total=sequences * frames, unit="frame", desc="synth", file=sys.stderr, dynamic_ncols=True) as bar:
            try:
                result = generate_capture(out, config, workers=workers, force=force, mano_path=settings.mano_path,
                                          progress=bar.update)
            except SynthError as exc:
                bar.close()
                typer.echo(f"error: {exc}", err=True)
                raise typer.Exit(code=2) from None
        typer.echo(f"wrote {result.num_frames} frames x {result.num_views} views to {result.root} in "
                   f"{result.seconds:.1f} s ({result.frames_per_s:.1f} frames/s)")
