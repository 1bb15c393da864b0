"""`handloop simulate --capture DIR --rounds 4`: the bootstrap D_0 ... D_n with simulated people on the
real server and workers (docs/evaluation.md)."""

from __future__ import annotations

import json
import logging
import sys
from datetime import UTC, datetime
from pathlib import Path

import typer

log = logging.getLogger("handloop.simulate")


def _parse_settings(pairs: list[str]) -> dict[str, object]:
    out: dict[str, object] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise typer.BadParameter(f"--set takes KEY=VALUE (a settings field), not {pair!r}")
        try:
            out[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            out[key.strip()] = value
    return out


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @app.command("simulate")
    def simulate(
        capture: Path = typer.Option(..., "--capture", help="A synthetic capture (with ground truth)."),
        rounds: int = typer.Option(4, min=0, max=50, help="Bootstrap rounds after D_0."),
        json_out: bool = typer.Option(False, "--json", help="Print the summary as the last stdout line."),
        out: Path | None = typer.Option(None, help="Folder for the report, plots and the started server "
                                                   "(default: <data dir>/simulations/<time>)."),
        initial_every: int = typer.Option(8, min=2, help="D_0: every k-th frame of each training sequence."),
        annotators: int = typer.Option(2, min=1, max=100),
        reviewers: int = typer.Option(1, min=1, max=100),
        click_sigma_px: float = typer.Option(2.0, help="Click noise, pixels (std per coordinate)."),
        swap_probability: float = typer.Option(0.05, help="Per view: two fingertips swapped."),
        mask_iou_threshold: float = typer.Option(0.5, help="Correct a shown mask with IoU below this."),
        max_mask_corrections: int = typer.Option(2, help="Most mask corrections per sample."),
        boundary_noise_px: float = typer.Option(1.5, help="Boundary noise of corrected masks, pixels."),
        accept_below_mm: float = typer.Option(8.0, help="Reviewers accept fits with a true mean vertex error "
                                                        "below this (mm)."),
        review_error_rate: float = typer.Option(0.02, help="Share of review decisions that are wrong."),
        reviewer_discards: int = typer.Option(0, help="From round 1 on, reviewers discard a sample's bad fit from "
                                              "predictions this many times (it waits for the next round's fit) "
                                              "before sending it to the annotators (bench sim-matrix uses 1); 0: "
                                              "every bad fit goes to the annotators."),
        reviewer_round0_floor: int | None = typer.Option(None, help="In round 0 reviewers discard a bad detector fit "
                                                         "the same way once D_0 holds this many labels; unset: "
                                                         "round 0's bad fits all go to the annotators."),
        click_s: float = typer.Option(2.0, help="Seconds per click."),
        mask_s: float = typer.Option(12.0, help="Seconds per mask correction."),
        verify_s: float = typer.Option(5.0, help="Seconds per verification."),
        accept_proposals_px: float | None = typer.Option(
            None, help="Annotators accept a shown proposal (detector, MVNet, fit) within this many pixels of the "
            "true point instead of clicking it (default: they click every point)."),
        proposal_s: float = typer.Option(1.0, help="Seconds to accept a view's proposals (one key; an assumption, "
                                                   "not a figure of the paper)."),
        seed: int = typer.Option(0),
        detector: str | None = typer.Option(None, "--detector", help="on: round 0 pre-annotated by the pretrained "
                                            "detector (the initial set goes to reviewers first); off: clicked "
                                            "from nothing (the paper). Default: on where the detector is installed "
                                            "(with --url: where that server can run it); the output says which."),
        nets: str = typer.Option("cpu-small", help="Networks trained each round: tiny, cpu-small or paper."),
        set_: list[str] = typer.Option([], "--set", help="Another server setting, KEY=VALUE (e.g. "
                                                         "round_mvnet_budget_s=300); repeatable."),
        worker_concurrency: int = typer.Option(1, min=1, max=64, help="Worker processes of the started stack."),
        round_timeout_s: float = typer.Option(3600.0, help="Longest wait for one round."),
        url: str | None = typer.Option(None, help="Use this running server instead of starting one."),
        admin_email: str | None = typer.Option(None, help="With --url: an admin's email."),
        admin_password: str | None = typer.Option(None, envvar="HANDLOOP_SIM_ADMIN_PASSWORD",
                                                  help="With --url: the admin's password."),
    ) -> None:
        """Simulated annotators and reviewers (driven by the capture's ground truth) run D_0 ... D_n through
        the real API and workers; reports per round the samples added by stream, human hours, the
        auto-accept precision, the accepted set's and MVNet's accuracy, and writes PNG plots."""
        from tqdm import tqdm

        from backend.settings import get_settings
        from backend.simulation.annotator import AnnotatorConfig
        from backend.simulation.bootstrap import BootstrapConfig
        from backend.simulation.costs import UnitCosts
        from backend.simulation.reviewer import ReviewerConfig
        from backend.simulation.runner import ServerOptions, run_simulation
        from workers.capture import CaptureError, read_capture

        def fail(message: str) -> None:
            typer.echo(f"error: {message}", err=True)
            raise typer.Exit(code=2)

        logging.getLogger("httpx").setLevel(logging.WARNING)  # one line per request drowns the progress
        try:
            parsed = read_capture(capture, check_images=False)
        except CaptureError as exc:
            fail(f"capture rejected: {exc}")
        if not any(seq.has_ground_truth for seq in parsed.sequences):
            fail(f"{capture} has no ground truth: the simulated people need a synthetic capture")
        if detector not in (None, "on", "off"):
            fail(f"--detector must be on or off, not {detector!r}")
        if url is None and detector != "off":  # the started stack shares this install: settled before it starts
            from backend.services.rounds.preannotation import detector_problem

            problem = detector_problem()
            if detector == "on" and problem is not None:
                fail(f"--detector on needs the pretrained detector: {problem}")
            if detector is None:
                detector = "on" if problem is None else "off"
                typer.echo(f"detector {detector} (the default: " + ("installed)" if problem is None
                                                                     else f"{problem})"), err=True)
        elif detector is None:
            typer.echo(f"detector on where the server at {url} can run it (the default)", err=True)
        try:
            config = BootstrapConfig(
                rounds=rounds, annotators=annotators, reviewers=reviewers,
                annotator=AnnotatorConfig(click_sigma_px=click_sigma_px, swap_probability=swap_probability,
                                          mask_iou_threshold=mask_iou_threshold,
                                          max_mask_corrections=max_mask_corrections,
                                          boundary_noise_px=boundary_noise_px,
                                          accept_proposals_within_px=accept_proposals_px, seed=seed),
                reviewer=ReviewerConfig(accept_below_mm=accept_below_mm, error_rate=review_error_rate,
                                        discards_before_annotation=reviewer_discards,
                                        round0_discard_floor=reviewer_round0_floor, seed=seed),
                costs=UnitCosts(click_s=click_s, mask_correction_s=mask_s, verification_s=verify_s,
                                proposal_view_s=proposal_s),
                round_timeout_s=round_timeout_s, detector=None if detector is None else detector == "on")
            server = ServerOptions(url=url, admin_email=admin_email, admin_password=admin_password,
                                   settings={"nets_config": nets, **_parse_settings(set_)},
                                   worker_concurrency=worker_concurrency)
        except ValueError as exc:
            fail(str(exc))
        work = out or get_settings().data_dir.resolve() / "simulations" / datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
        if work.exists() and any(work.iterdir()):
            fail(f"{work} is not empty; choose another --out")
        with tqdm(total=rounds + 1, unit="round", desc="bootstrap", file=sys.stderr) as bar:
            def on_round(report) -> None:
                bar.set_postfix(D=report.dataset_size, hours=f"{report.human_hours_cumulative:.2f}")
                bar.update(1)

            try:
                summary = run_simulation(capture, work, config, initial_every=initial_every, server=server,
                                         on_round=on_round)
            except ValueError as exc:
                fail(str(exc))
        if json_out:
            sys.stdout.write(json.dumps(summary) + "\n")
            return
        for r in summary["rounds"]:
            typer.echo(f"D_{r['index']}: {r['dataset_size']:5d} samples  +{r['added']['heuristic']} heuristic "
                       f"+{r['added']['manual']} manual +{r['added']['annotated']} annotated  "
                       f"{r['human_hours']:.2f} h  accepted {_mm(r['accepted_vertex_mm'])}  "
                       f"MVNet {_mm(r['mvnet_keypoint_mm'])}")
        typer.echo(f"detector {'on' if summary['detector'] else 'off'}; D_0 verified alone: "
                   f"{summary['d0_verified_share']}")
        typer.echo(f"labels per human hour: {summary['labels_per_human_hour']}; report in {work}")
        if summary["failure"]:
            typer.echo(f"stopped early: {summary['failure']}", err=True)


def _mm(value: float | None) -> str:
    return "   n/a  " if value is None else f"{value:6.2f} mm"
