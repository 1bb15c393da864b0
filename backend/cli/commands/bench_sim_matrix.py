"""`handloop bench sim-matrix`: the loop over unseen seeds, widths, people and proposals (docs/evaluation.md)."""

from __future__ import annotations

import logging
from pathlib import Path

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("sim-matrix")
    def bench_sim_matrix(
        cells: str = typer.Option(
            "all", "--cells", help="all, headline (640-default-proposals and 320-noisy-no-proposals, the issue's "
            "targets), or cell names separated by commas: WIDTH-PEOPLE-PROPOSALS with WIDTH 320 or 640, PEOPLE "
            "default or noisy, PROPOSALS proposals or no-proposals."),
        seeds: str | None = typer.Option(
            None, "--seeds", help="Seeds separated by commas (capture and people). Default: the matrix's unseen "
            "seeds, which no test or tuning uses; others are recorded as such."),
        out: Path | None = typer.Option(
            None, "--out", help="Folder of matrix.json (written as each run finishes), matrix.png and the runs' "
            "work folders. Default: <data_dir>/bench/sim-matrix."),
        resume: bool = typer.Option(False, "--resume", help="Finish the matrix in --out: run only what it lacks."),
        quick: bool = typer.Option(False, "--quick", help="Reduced runs (bench sim --quick's plan at the cells' "
                                   "widths): checks that the matrix works, does not judge the loop."),
        rounds: int | None = typer.Option(None, "--rounds", help="Rounds after D_0 (default 4; --quick 1)."),
        frames: int | None = typer.Option(None, "--frames", help="Frames per sequence (default 20; --quick 8)."),
        train_steps: int | None = typer.Option(None, "--train-steps", min=1,
                                               help="Training steps of each network a round (default 650)."),
        handsegnet_steps: int | None = typer.Option(None, "--handsegnet-steps", min=1,
                                                    help="HandSegNet's own training steps a round (default 1650)."),
        detector: str = typer.Option("on", "--detector", help="on (round 0 pre-annotated by the pretrained "
                                     "detector, as the loop runs; refused where it cannot run) or off."),
        reviewer_discards: int = typer.Option(
            1, "--reviewer-discards", min=0, max=100, help="How many times the simulated reviewers discard a sample's "
            "bad fit from predictions from round 1 on (it waits for the next round's fit) before they send it to the "
            "annotators, as the paper's reviewers discarded most fits; 0: every bad fit goes to the annotators (the "
            "matrix's reviewers until 2026-12-07)."),
        reviewer_round0_floor: int | None = typer.Option(
            None, "--reviewer-round0-floor", min=0, max=1_000_000, help="In round 0 the simulated reviewers discard "
            "a bad detector fit the same way once D_0 holds this many labels; unset: round 0's bad fits all go to "
            "the annotators."),
        review_capacity: int | None = typer.Option(
            None, "--review-capacity", help="Fits the reviewers can verify in a round, round 0's too (the stack's "
            "review_capacity_per_round, e.g. 1000 as the paper verified in its round 1): the queue filled to it by "
            "confidence; unset: the setting's default (0, the fixed policy: median cut and time gap)."),
    ) -> None:
        """Step-counted bootstrap simulations per cell and seed, one after the other: a markdown table of the
        median and worst seed per cell, a plot, and one JSON object as the last stdout line."""

        from backend.bench.sim_matrix import parse_cells, parse_seeds, run

        logging.getLogger("httpx").setLevel(logging.WARNING)  # one line per request drowns the progress
        try:
            run(cells=parse_cells(cells), seeds=parse_seeds(seeds), out_dir=out, resume=resume, quick=quick,
                rounds=rounds, frames=frames, train_steps=train_steps, handsegnet_steps=handsegnet_steps,
                detector=detector, reviewer_discards=reviewer_discards, reviewer_round0_floor=reviewer_round0_floor,
                review_capacity=review_capacity)
        except ValueError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=2) from exc
