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
        mvnet: str = typer.Option("both", "--mvnet", help="Which MVNet: paper (paper-only), detector "
                                  "(detector-backed) or both, side by side."),
        frames_per_sequence: int | None = typer.Option(
            None, "--frames-per-sequence", min=1, max=1000,
            help="Frames per synthetic sequence instead of the size's (60 full, 4 quick); budgets unchanged."),
        mvnet_steps: int | None = typer.Option(
            None, "--mvnet-steps", min=1, max=1_000_000,
            help="Train every MVNet for exactly this many steps instead of the time budget (load-independent)."),
        detector_config: str = typer.Option("cpu-small-detector", "--detector-config",
                                             help="Configuration of the detector-backed MVNet."),
    ) -> None:
        """Train on green-screen sequences, evaluate on held-out subjects in front of other backgrounds."""
        from backend.bench.nets import MVNET_CHOICES, run
        from workers.nets.configs import CONFIGS

        if mvnet not in MVNET_CHOICES:
            raise typer.BadParameter(f"choose one of {', '.join(MVNET_CHOICES)}", param_hint="--mvnet")
        for name, hint in ((config, "--config"), (detector_config, "--detector-config")):
            if name not in CONFIGS:
                raise typer.BadParameter(f"unknown configuration {name!r}; choose from {sorted(CONFIGS)}",
                                         param_hint=hint)
        if CONFIGS[detector_config].mvnet.heatmap_source != "detector" and mvnet != "paper":
            raise typer.BadParameter(f"{detector_config!r} is not detector-backed", param_hint="--detector-config")
        record = run(quick=quick, data_dir=data, out_dir=out, seed=seed, config_name=config, threads=threads,
                     emit_json=json_out, mvnet=mvnet, detector_config_name=detector_config,
                     frames_per_sequence=frames_per_sequence, mvnet_steps=mvnet_steps)
        if not json_out:
            side = record["side_by_side"]
            typer.echo(f"MVNet paper-only / detector-backed: {side['keypoint_mm']['paper']} / "
                       f"{side['keypoint_mm']['detector']} mm (AUC {side['auc']['paper']} / {side['auc']['detector']}),"
                       f" gt-centred {side['keypoint_mm_gt_center']['paper']} / "
                       f"{side['keypoint_mm_gt_center']['detector']} mm, {side['inference_ms']['paper']} / "
                       f"{side['inference_ms']['detector']} ms per frame; HandSegNet IoU {record['handsegnet_iou']}"
                       + (f"; {record['detector_status']}" if record["detector_status"] else ""))
