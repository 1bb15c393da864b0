"""`handloop bench sim`: the bootstrap simulation against the issue's targets (docs/benchmarks.md)."""

from __future__ import annotations

import logging

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("sim")
    def bench_sim(
        json_out: bool = typer.Option(False, "--json", help="Print the JSON record as the last stdout line."),
        quick: bool = typer.Option(False, "--quick", help="Reduced run (tiny networks, 24 frames, 1 round)."),
        detector: str | None = typer.Option(
            None, "--detector", help="on, off, or both (the same capture and seed side by side). Default: both "
            "where the pretrained detector can run, else off."),
        accept_proposals_px: float | None = typer.Option(
            None, help="Simulated annotators accept a shown proposal within this many pixels of the true point "
            "(one key per view) instead of clicking it; default: they click every point."),
        width: int | None = typer.Option(None, "--width", help="View width in pixels (default 320; --quick 128)."),
        frames: int | None = typer.Option(None, "--frames", help="Frames per sequence, 15 per second of capture "
                                          "(default 20; --quick 8). The review policy picks frames 1 s apart."),
        rounds: int | None = typer.Option(None, "--rounds",
                                          help="Bootstrap rounds after D_0 (default 4; --quick 1; 0: D_0 alone)."),
        initial_every: int | None = typer.Option(None, "--initial-every", min=2,
                                                 help="D_0's plan: every k-th training frame (default 8; --quick 4)."),
        round0_rest: str = typer.Option(
            "keep", "--round0-rest", help="With the detector, the initial set's samples the review policy does "
            "not pick: keep (left for round 1's MVNet, as the paper leaves every round's unpicked samples; only fits "
            "sent back are annotated) or annotate (clicked in round 0)."),
        round0_frames: str = typer.Option(
            "all", "--round0-frames", help="With the detector, the training frames pre-annotated in round 0: all "
            "(its heuristic accepts what it can; reviewers see the rest by the queue policy) or initial (the initial "
            "set only, every k-th frame)."),
        train_steps: int | None = typer.Option(
            None, "--train-steps", min=1, help="Each network trains this many steps a round instead of for the time "
            "budgets: runs then repeat exactly (to compare variants); default: the budgets, as users run."),
        handsegnet_steps: int | None = typer.Option(
            None, "--handsegnet-steps", min=1, help="HandSegNet alone trains this many steps a round, in place of "
            "--train-steps (with it: MVNet's steps held while HandSegNet's vary)."),
        seed: int = typer.Option(2026, "--seed", min=0, help="The capture's, the simulated people's and the audits' "
                                 "seed (default 2026)."),
        audit_share: float = typer.Option(0.05, "--audit-share", min=0.0, max=1.0, help="Share of each stream's "
                                          "accepts the server audits blind (issue 40; default 0.05, 0: none)."),
        precision_target: float | None = typer.Option(
            None, "--precision-target", help="The server's 'at most this share of auto-accepted labels wrong' "
            "(e.g. 0.02); checked on the true labels (label_quality); default: off, checked against 0.02."),
        reviewer_error_rate: float | None = typer.Option(None, "--reviewer-error-rate", min=0.0, max=1.0,
                                                         help="Simulated reviewers' decision error (default 0.02)."),
        reviewer_accept_below_mm: float | None = typer.Option(
            None, "--reviewer-accept-below-mm", help="Simulated reviewers accept a fit under this true mean vertex "
            "error (default 8 mm)."),
        gold_labels: int = typer.Option(0, "--gold-labels", min=0, max=10_000, help="After D_0 the admin marks this "
                                        "many truly right accepted labels gold (default 0)."),
        agreement_share: float = typer.Option(0.0, "--agreement-share", min=0.0, max=1.0, help="Share of annotated "
                                              "samples annotated twice, blind, by another annotator (default 0)."),
        click_sigma_px: float | None = typer.Option(None, "--click-sigma-px", min=0.0, max=100.0,
                                                    help="Simulated annotators' click noise per coordinate (2 px)."),
        swap_probability: float | None = typer.Option(None, "--swap-probability", min=0.0, max=1.0,
                                                      help="Simulated annotators' fingertip swaps per view (0.05)."),
        gold_share: float = typer.Option(0.0, "--gold-share", min=0.0, max=1.0, help="Share of the reviewers' tasks "
                                         "that are gold labels (default 0)."),
    ) -> None:
        """200-frame synthetic capture, cpu-small networks, 4 rounds through the real server and workers:
        minutes, accepted labels' vertex error, auto-accept precision, labels per human hour; with the
        detector on and off side by side."""

        from backend.bench.sim import DETECTOR_MODES, by_kind_line, run

        if detector is not None and detector not in DETECTOR_MODES:
            typer.echo(f"error: --detector must be one of {', '.join(DETECTOR_MODES)}, not {detector!r}", err=True)
            raise typer.Exit(code=2)
        logging.getLogger("httpx").setLevel(logging.WARNING)  # one line per request drowns the progress
        try:
            record = run(quick=quick, emit_json=json_out, detector=detector, accept_proposals_px=accept_proposals_px,
                         width=width, rounds=rounds, initial_every=initial_every, round0_rest=round0_rest,
                         frames=frames, train_steps=train_steps,
                         handsegnet_steps=handsegnet_steps, seed=seed, audit_share=audit_share,
                         precision_target=precision_target, reviewer_error_rate=reviewer_error_rate,
                         reviewer_accept_below_mm=reviewer_accept_below_mm, gold_labels=gold_labels,
                         gold_share=gold_share, round0_frames=round0_frames, agreement_share=agreement_share,
                         click_sigma_px=click_sigma_px, swap_probability=swap_probability)
        except ValueError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=2) from exc
        if not json_out:
            for mode, rows in (record.get("side_by_side") or {}).items():
                for r in rows:
                    so_far = ("" if r["heuristic_share_cumulative"] is None
                              else f", {r['heuristic_share_cumulative']:.1%} of the fitted so far")
                    typer.echo(f"detector {mode} D_{r['index']}: +{r['heuristic']} Dh (precision "
                               f"{r['auto_accept_precision']}{so_far}) +{r['manual']} Dm +{r['annotated']} Dl, "
                               f"{r['labels_per_human_hour']} labels/h, accepted {r['accepted_vertex_mm']} mm")
                    if r["index"] > 0:
                        typer.echo(f"  {by_kind_line(r)}")
            for r in record["rounds"]:
                typer.echo(f"D_{r['index']}: {r['dataset_size']} samples, {r['human_hours']:.2f} h")
            for stream, q in (record.get("label_quality") or {}).items():
                if stream == "gold":
                    continue
                typer.echo(f"{stream}: audited {q['audited']}, audit error {q['audit_error_rate']} "
                           f"{q['audit_error_rate_ci95']}, true {q['true_error_rate']} over {q['labels']} labels")
            typer.echo(f"minutes {record['minutes']:.1f}  accepted {record['accepted_vertex_mm']} mm  "
                       f"auto-accept precision {record['auto_accept_precision']}  "
                       f"labels/h {record['labels_per_human_hour']}")
        for simulated in (record, record.get("detector_off") or {}):
            stopped = simulated.get("stopped")
            if stopped:  # the run ended cleanly before its last round; the record says where and why
                typer.echo(f"detector {'on' if simulated.get('detector') else 'off'}: stopped in round "
                           f"{stopped['round']}: {stopped['reason']}", err=True)
