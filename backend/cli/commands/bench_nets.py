"""`handloop bench nets`: train HandSegNet and MVNet (`cpu-small`) on synthetic frames within a budget and
evaluate keypoint error, mask IoU, confidence quality (sparsification) and inference time."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("nets")
    def bench_nets(
        json_out: bool = typer.Option(False, "--json", help="Print the JSON record as the last stdout line."),
        quick: bool = typer.Option(False, "--quick", help="Reduced run (about a minute)."),
        data: Path | None = typer.Option(None, "--data", help="Folder caching the synthetic capture."),
        out: Path | None = typer.Option(None, "--out", help="Folder for checkpoints and the sparsification plot."),
        seed: int = typer.Option(0, min=0, help="Seed of the capture, initialisation and batches."),
        config: str = typer.Option("cpu-small", help="Network configuration."),
        threads: int = typer.Option(1, min=1, max=256, help="torch CPU threads (1 suits a shared machine)."),
    ) -> None:
        """Train on green-screen sequences, evaluate on held-out subjects in front of other backgrounds."""
        from backend.bench.nets import run

        record = run(quick=quick, data_dir=data, out_dir=out, seed=seed, config_name=config, threads=threads,
                     emit_json=json_out)
        if not json_out:
            typer.echo(f"MVNet {record['mvnet_keypoint_mm']} mm (AUC {record['mvnet_auc']}), HandSegNet IoU "
                       f"{record['handsegnet_iou']}, AUSE score-volume {record['ause_scorevolume']} / soft-argmax "
                       f"{record['ause_softargmax']} mm, {record['train_minutes']:.1f} min training, "
                       f"{record['inference_ms']:.0f} ms per frame")
