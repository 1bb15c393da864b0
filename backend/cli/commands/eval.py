"""`handloop eval PRED GT`: FreiHAND's benchmark metrics of a prediction file against a dataset folder."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @app.command("eval")
    def eval_(
        pred: Path = typer.Argument(..., help="pred.json ([xyz_list, verts_list], metres) or a folder holding it."),
        gt: Path = typer.Argument(..., help="Dataset folder with <set>_xyz.json and <set>_verts.json "
                                            "(FreiHAND's, or one written by `handloop export --format freihand`)."),
        set_name: str = typer.Option("evaluation", "--set", help="Which split's files: evaluation or training."),
        json_out: bool = typer.Option(False, "--json", help="Print the scores as one JSON object (last stdout line)."),
        curves: bool = typer.Option(True, help="Include the PCK curves in the JSON."),
        scores_txt: Path | None = typer.Option(None, "--scores-txt",
                                               help="Also write the official scores.txt lines to this file."),
    ) -> None:
        """PCK (100 thresholds, 0-50 mm) and AUC, mean keypoint and vertex errors raw and Procrustes-aligned
        (with scale), and F-scores at 5 and 15 mm, named as FreiHAND's official evaluation names them."""
        from tqdm import tqdm

        from workers.evaluation import EvaluationInputError, check_pair, evaluate, load_ground_truth, load_predictions

        try:
            gt_sets = load_ground_truth(gt, set_name)
            pred_sets = load_predictions(pred)
            check_pair(pred_sets, gt_sets)
        except EvaluationInputError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=2) from exc
        with tqdm(total=len(gt_sets), unit="sample", desc="evaluating", file=sys.stderr) as bar:
            scores = evaluate(gt_sets.xyz, gt_sets.verts, pred_sets.xyz, pred_sets.verts, progress=bar.update)
        record = scores.to_dict(with_curves=curves)
        record.update(prediction=pred_sets.source, ground_truth=gt_sets.source, set=set_name)
        if scores_txt is not None:
            scores_txt.write_text(_scores_txt(record))
        if json_out:
            sys.stdout.write(json.dumps(record) + "\n")
            return
        for key in ("xyz_mean3d_mm", "xyz_auc3d", "xyz_al_mean3d_mm", "xyz_al_auc3d", "mesh_mean3d_mm", "mesh_auc3d",
                    "mesh_al_mean3d_mm", "mesh_al_auc3d", "f_score_5", "f_al_score_5", "f_score_15", "f_al_score_15"):
            value = record[key]
            typer.echo(f"{key:<18} {'n/a (meshes differ)' if value is None else f'{value:.4f}'}")


def _scores_txt(record: dict) -> str:
    """The official scores.txt lines (mean3d in cm; -1 where the official script writes it: no meshes)."""
    keys = ("xyz_mean3d", "xyz_auc3d", "xyz_al_mean3d", "xyz_al_auc3d", "mesh_mean3d", "mesh_auc3d",
            "mesh_al_mean3d", "mesh_al_auc3d", "f_score_5", "f_al_score_5", "f_score_15", "f_al_score_15")
    return "".join(f"{key}: {(-1.0 if record[key] is None else record[key]):f}\n" for key in keys)
