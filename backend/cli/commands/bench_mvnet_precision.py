"""`handloop bench mvnet-precision`: the detector's lifted keypoints against the detector-backed MVNet untrained and
after N training steps, on held-out green-screen frames (step budgets: load-independent)."""

from __future__ import annotations

from pathlib import Path

import typer


def _steps(text: str) -> list[int]:
    try:
        steps = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise typer.BadParameter(f"not a comma-separated list of step counts: {text!r}", param_hint="--steps") from None
    if not steps or any(n < 1 for n in steps):
        raise typer.BadParameter(f"step counts must be positive, got {text!r}", param_hint="--steps")
    return steps


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("mvnet-precision")
    def bench_mvnet_precision(
        json_out: bool = typer.Option(False, "--json", help="Print the JSON record as the last stdout line."),
        data: Path | None = typer.Option(None, "--data", help="Folder caching the capture, detections, checkpoints."),
        width: int = typer.Option(640, min=128, max=2048, help="View width of the synthetic capture, pixels."),
        sequences: int = typer.Option(8, min=4, max=64, help="Synthetic sequences (2 of them evaluation)."),
        frames: int = typer.Option(12, min=4, max=200, help="Frames per sequence."),
        seed: int = typer.Option(1515, min=0, help="Seed of the capture, initialisation and batches."),
        config: list[str] = typer.Option(["cpu-small-detector"], "--config",
                                         help="Detector-backed configuration(s), NAME or NAME:FIELD=VALUE,... "
                                         "(MVNet fields replaced); repeat to compare."),
        steps: str = typer.Option("100,300", "--steps", help="Training step counts, each from scratch."),
        threads: int = typer.Option(1, min=1, max=256, help="torch CPU threads."),
        heuristic: bool = typer.Option(True, "--heuristic/--no-heuristic",
                                       help="Fit the held-out frames from the last step count's predictions and "
                                            "apply the paper's heuristic (ground-truth hand masks, chroma key)."),
    ) -> None:
        """Lift vs untrained vs trained detector-backed MVNet against ground truth, green-screen frames."""
        from backend.bench.mvnet_precision import parse_config, run

        counts = _steps(steps)
        for name in config:
            try:
                parsed = parse_config(name)
            except (ValueError, TypeError) as exc:
                raise typer.BadParameter(str(exc), param_hint="--config") from exc
            if parsed.mvnet.heatmap_source != "detector":
                raise typer.BadParameter(f"{name!r} is not detector-backed", param_hint="--config")
        record = run(data_dir=data, width=width, sequences=sequences, frames=frames, seed=seed, configs=config,
                     steps=counts, threads=threads, heuristic=heuristic, emit_json=json_out)
        if not json_out:
            for key, stats in record["lift"].items():
                typer.echo(f"lift {key}: median {stats['median_mm']} mm, mean {stats['mean_mm']} mm")
            for name, result in record["configs"].items():
                for stage, sets in result.items():
                    figures = ", ".join(f"{k} {v['median_mm']}/{v['mean_mm']} mm" for k, v in sets.items()
                                        if isinstance(v, dict) and "median_mm" in v)
                    typer.echo(f"{name} {stage}: {figures}")
