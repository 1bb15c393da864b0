"""`handloop bench sim-matrix`: its cells, figures, results file (written as runs finish, resumed), table, plot and
JSON line, with the simulation replaced by canned summaries; and one reduced real run (slow) that only checks the
matrix works end to end. None of this judges the loop: that is the matrix run on its unseen seeds."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from backend.bench import sim, sim_matrix
from backend.cli.main import app
from backend.settings import get_settings

runner = CliRunner()
SEEDS = (11, 12, 13)  # the tests' own: never the matrix's UNSEEN_SEEDS


def _round(index: int, added: int, hours: float, evaluated: int = 0, accepted: int = 0,
           mvnet_mm: float | None = None) -> dict:
    # The review ranks' Spearman (rounds >= 1): the confidence's falls with the round's heuristic accepts.
    quality = {"by_rank": {"confidence": {"spearman": 0.5 - accepted / 100}, "agreement": {"spearman": 0.8}}}
    return {"index": index, "added": {"heuristic": accepted, "manual": 0, "annotated": added - accepted},
            "added_total": added, "human_hours": hours, "mvnet_keypoint_mm": mvnet_mm,
            "round_job": {"heuristic": {"evaluated": evaluated, "accepted": accepted}} if index else None,
            "rank_quality": quality if index else None}


def fake_summary(seed: int, annotator) -> dict:
    """A 2-round run whose figures follow from the seed: D_0 10 labels in 0.1 h; round 1 20 (of them `seed`
    accepted by the heuristic of 100 fitted) in 0.05 h; round 2 30 (5 accepted) in 0.05 h."""
    rounds = [_round(0, 10, 0.1), _round(1, 20, 0.05, 100, seed, 30.0), _round(2, 30, 0.05, 80, 5, 20.0 + seed)]
    size = sum(r["added_total"] for r in rounds)
    return {"rounds": rounds, "rounds_completed": 2, "stopped": None, "dataset_size": size, "human_hours": 0.2,
            "labels_per_human_hour": size / 0.2, "auto_accept_precision": 1.0 - seed / 100,
            "accepted_vertex_mm": 4.0 + seed / 10, "bookkeeping_ok": True, "minutes": 1.0,
            "d0_verified_share": 0.5, "people": (annotator.click_sigma_px, annotator.swap_probability,
                                                  annotator.accept_proposals_within_px, annotator.seed)}


@pytest.fixture
def fakes(monkeypatch, tmp_path):
    """The simulation and the capture replaced; the calls (cell width, seed, people, detector) recorded."""
    calls = []

    def fake_simulate(capture, work, plan, *, detector, annotator, reviewer, label, leave):
        calls.append({"width": plan["width"], "rounds": plan["rounds"], "seed": annotator.seed,
                      "reviewer_seed": reviewer.seed, "discards": reviewer.discards_before_annotation,
                      "round0_floor": reviewer.round0_discard_floor,
                      "detector": detector, "label": label,
                      "settings": plan["settings"], "capture": capture})
        if getattr(fake_simulate, "interrupt_at", None) == len(calls):
            raise KeyboardInterrupt
        return fake_summary(annotator.seed, annotator)

    monkeypatch.setattr(sim, "simulate", fake_simulate)
    monkeypatch.setattr(sim, "synthetic_capture", lambda root, sequences, frames, width, seed: tmp_path / f"{seed}")
    monkeypatch.setattr(sim_matrix.preannotation, "detector_problem", lambda: None)
    monkeypatch.setenv("HANDLOOP_DATA_DIR", str(tmp_path / "data"))
    get_settings.cache_clear()
    yield fake_simulate, calls
    get_settings.cache_clear()


def _invoke(*args: str):
    return runner.invoke(app, ["bench", "sim-matrix", *args])


def test_the_matrix_runs_each_cell_and_seed_and_reports_median_and_worst(fakes, tmp_path):
    _, calls = fakes
    out = tmp_path / "m"
    result = _invoke("--cells", "headline", "--seeds", "11,12,13", "--out", str(out))
    assert result.exit_code == 0, result.output[-3000:]
    # Each headline cell once per seed, step-counted at the steps, with the detector, seeded people.
    assert [(c["width"], c["seed"]) for c in calls] == [(640, 11), (640, 12), (640, 13), (320, 11), (320, 12),
                                                        (320, 13)]
    assert all(c["reviewer_seed"] == c["seed"] and c["detector"] and c["rounds"] == 4 for c in calls)
    assert calls[0]["settings"]["round_max_train_steps"] == 650
    assert calls[0]["settings"]["round_handsegnet_max_steps"] == 1650
    assert calls[0]["capture"] == tmp_path / "11"  # the capture synthesised with the run's seed
    record = json.loads(result.stdout.strip().splitlines()[-1])
    assert record["benchmark"] == "sim-matrix" and record["seeds_unseen"] is False
    runs = {(r["cell"], r["seed"]): r for r in record["runs"]}
    # The people of each cell: the defaults taking proposals within 4 px; the noisy ones clicking every point.
    assert json.loads((out / "matrix.json").read_text())["runs"]["640-default-proposals/seed11"]["cell"]
    headline, noisy = record["cells"]
    assert headline["cell"] == "640-default-proposals" and noisy["cell"] == "320-noisy-no-proposals"
    assert headline["seeds"] == [11, 12, 13] and headline["stopped"] == 0
    # Per seed: 60 labels in 0.2 h (300 / h); by round 2 the same; the heuristic's (seed + 5) of 100 by round 2.
    assert runs[("640-default-proposals", 12)]["labels_per_human_hour_by_round"] == pytest.approx([100, 200, 300])
    assert headline["labels_per_human_hour"] == pytest.approx({"median": 300.0, "worst": 300.0})
    assert headline["heuristic_share_by_round_2"] == pytest.approx({"median": 0.17, "worst": 0.16})
    assert headline["auto_accept_precision"] == pytest.approx({"median": 0.88, "worst": 0.87})
    assert headline["mvnet_keypoint_mm"] == pytest.approx({"median": 32.0, "worst": 33.0})  # the last round's
    assert headline["accepted_vertex_mm"] == pytest.approx({"median": 5.2, "worst": 5.3})
    assert headline["additions_per_round"] == [10, 20, 30] and headline["additions_grow"] is True
    # The targets: 300 < 600 labels / h and 17 % < 40 % missed; additions grow, 5.2 mm <= 6 mm met. The 320 cell's
    # "by round 4" is not measured in a 2-round run, so not met.
    assert headline["targets_met"] == {"labels_per_human_hour_by_round_2": False,
                                       "heuristic_share_by_round_2": False,
                                       "additions_grow": True, "accepted_vertex_mm": True}
    assert noisy["targets_met"]["labels_per_human_hour_by_round_4"] is False
    # The table: one row per cell, the figures as median / worst.
    lines = result.stdout.splitlines()
    row = next(line for line in lines if line.startswith("| 640-default-proposals |"))
    assert "| 3 (0) | 300.0 / 300.0 | 300.0 / 300.0 | 17.0% / 16.0% | 0.880 / 0.870 | 10 / 20 / 30 |" in row
    assert row.endswith("| 32.0 / 33.0 | 5.20 / 5.30 | 0.38 / 0.80 |") and record["table"].splitlines()[2] == row
    # Round 1's review ranks against the fits' true error: per run by round, the cell's median of round 1.
    assert runs[("640-default-proposals", 12)]["rank_spearman_by_round"] == [
        None, {"confidence": pytest.approx(0.38), "agreement": 0.8}, {"confidence": 0.45, "agreement": 0.8}]
    assert headline["rank_spearman_round_1"] == pytest.approx({"confidence": 0.38, "agreement": 0.8})
    assert Path(record["plot"]).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cells_name_their_people_and_proposals():
    cells = sim_matrix.parse_cells("320-noisy-proposals,640-default-no-proposals")
    assert [c.name for c in cells] == ["320-noisy-proposals", "640-default-no-proposals"]
    noisy, plain = (c.annotator(5) for c in cells)
    assert (noisy.click_sigma_px, noisy.swap_probability, noisy.accept_proposals_within_px) == (3.0, 0.08, 4.0)
    assert (plain.click_sigma_px, plain.swap_probability, plain.accept_proposals_within_px) == (2.0, 0.05, None)
    assert noisy.seed == plain.seed == 5
    assert len(sim_matrix.parse_cells("all")) == 8 and sim_matrix.parse_seeds(None) == sim_matrix.UNSEEN_SEEDS


def test_an_interrupted_matrix_keeps_its_finished_runs_and_resumes_the_rest(fakes, tmp_path):
    fake_simulate, calls = fakes
    out = tmp_path / "m"
    fake_simulate.interrupt_at = 3
    args = ("--cells", "320-default-proposals", "--seeds", "11,12,13,14", "--out", str(out), "--rounds", "2")
    result = _invoke(*args)
    assert result.exit_code == 130  # click: interrupted
    kept = json.loads((out / "matrix.json").read_text())["runs"]
    assert sorted(kept) == ["320-default-proposals/seed11", "320-default-proposals/seed12"]
    (out / "runs" / "320-default-proposals-seed13").mkdir(parents=True)  # the interrupted run's leftovers
    fake_simulate.interrupt_at = None
    result = _invoke(*args)
    assert result.exit_code == 2 and "exists: pass --resume" in result.output
    result = _invoke(*args, "--resume")
    assert result.exit_code == 0, result.output[-3000:]
    assert [c["seed"] for c in calls] == [11, 12, 13, 13, 14]  # only what the file lacked, 13 again
    assert not (out / "runs" / "320-default-proposals-seed13").exists()  # the leftovers cleared for the new run
    record = json.loads(result.stdout.strip().splitlines()[-1])
    assert record["cells"][0]["runs"] == 4 and len(json.loads((out / "matrix.json").read_text())["runs"]) == 4
    result = _invoke(*args[:-2], "--rounds", "3", "--resume")
    assert result.exit_code == 2 and "other settings (plan differ)" in result.output, result.output


def test_the_reviewers_discards_reach_each_run_and_are_part_of_the_results_config(fakes, tmp_path):
    _, calls = fakes
    out = tmp_path / "m"
    args = ("--cells", "320-default-proposals", "--seeds", "11", "--out", str(out), "--rounds", "2")
    assert _invoke(*args).exit_code == 0
    assert [c["discards"] for c in calls] == [sim_matrix.REVIEWER_DISCARDS] == [1]
    config = json.loads((out / "matrix.json").read_text())["config"]
    assert config["reviewer"]["discards_before_annotation"] == 1
    result = _invoke(*args, "--resume", "--reviewer-discards", "0")  # another setting
    assert result.exit_code == 2 and "other settings (reviewer differ)" in result.output, result.output
    # A results file from before the option: its reviewers never discarded, so it resumes under the default.
    data = json.loads((out / "matrix.json").read_text())
    del data["config"]["reviewer"]["discards_before_annotation"]
    data["runs"] = {}
    (out / "matrix.json").write_text(json.dumps(data))
    assert _invoke(*args, "--resume").exit_code == 2
    result = _invoke(*args, "--resume", "--reviewer-discards", "0")
    assert result.exit_code == 0, result.output[-3000:]
    assert [c["discards"] for c in calls] == [1, 0]
    assert _invoke(*args, "--reviewer-discards", "-1").exit_code == 2


def test_the_reviewers_round0_floor_reaches_each_run_and_old_results_resume_without_it(fakes, tmp_path):
    _, calls = fakes
    out = tmp_path / "m"
    args = ("--cells", "320-default-proposals", "--seeds", "11", "--out", str(out), "--rounds", "2")
    assert _invoke(*args, "--reviewer-round0-floor", "30").exit_code == 0
    assert calls[-1]["round0_floor"] == 30
    data = json.loads((out / "matrix.json").read_text())
    assert data["config"]["reviewer"]["round0_discard_floor"] == 30
    result = _invoke(*args, "--resume")  # the default has no floor: another setting
    assert result.exit_code == 2 and "other settings (reviewer differ)" in result.output, result.output
    # A results file from before the option: round 0 never discarded, so it resumes without a floor.
    del data["config"]["reviewer"]["round0_discard_floor"]
    data["runs"] = {}
    (out / "matrix.json").write_text(json.dumps(data))
    assert _invoke(*args, "--resume", "--reviewer-round0-floor", "30").exit_code == 2
    result = _invoke(*args, "--resume")
    assert result.exit_code == 0, result.output[-3000:]
    assert [c["round0_floor"] for c in calls] == [30, sim_matrix.REVIEWER_ROUND0_FLOOR]
    assert _invoke(*args, "--reviewer-round0-floor", "-1").exit_code == 2


def test_the_review_capacity_reaches_each_run_s_stack_and_old_results_resume_without_it(fakes, tmp_path):
    _, calls = fakes
    out = tmp_path / "m"
    args = ("--cells", "640-default-proposals", "--seeds", "11", "--out", str(out), "--rounds", "2")
    assert _invoke(*args, "--review-capacity", "1000").exit_code == 0
    assert calls[-1]["settings"]["review_capacity_per_round"] == 1000
    data = json.loads((out / "matrix.json").read_text())
    assert data["config"]["stack_settings"]["review_capacity_per_round"] == 1000
    result = _invoke(*args, "--resume")  # without it: the setting's default, another setting
    assert result.exit_code == 2 and "other settings" in result.output, result.output
    # A results file from before the option: its stack had the setting's default, so it resumes without one.
    del data["config"]["stack_settings"]["review_capacity_per_round"]
    data["runs"] = {}
    (out / "matrix.json").write_text(json.dumps(data))
    result = _invoke(*args, "--resume")
    assert result.exit_code == 0, result.output[-3000:]
    assert "review_capacity_per_round" not in calls[-1]["settings"]
    result = _invoke(*args[:-2], "--out", str(tmp_path / "never"), "--review-capacity", "1000001")
    assert result.exit_code == 2 and "review capacity must be in 0..1000000" in result.output, result.output
    assert not (tmp_path / "never").exists()


def test_settings_set_in_the_environment_are_recorded_and_must_match_on_resume(fakes, tmp_path, monkeypatch):
    out = tmp_path / "m"
    args = ("--cells", "640-default-proposals", "--seeds", "11", "--out", str(out), "--rounds", "2")
    monkeypatch.setenv("HANDLOOP_PREANNOTATION_REVIEW_CAPACITY", "1000")  # reaches the stack: recorded
    monkeypatch.setenv("HANDLOOP_SECRET_KEY", "do-not-record-this-secret")  # secret-like, and plumbing: never recorded
    monkeypatch.setenv("HANDLOOP_WORKER_CONCURRENCY", "2")
    assert _invoke(*args).exit_code == 0
    data = json.loads((out / "matrix.json").read_text())
    assert data["config"]["environment"] == {"preannotation_review_capacity": "1000"}
    assert "do-not-record-this-secret" not in (out / "matrix.json").read_text()
    monkeypatch.delenv("HANDLOOP_PREANNOTATION_REVIEW_CAPACITY")
    result = _invoke(*args, "--resume")
    assert result.exit_code == 2 and "other settings (environment differ)" in result.output, result.output
    # A results file from before the environment was recorded resumes where none is set.
    del data["config"]["environment"]
    data["runs"] = {}
    (out / "matrix.json").write_text(json.dumps(data))
    result = _invoke(*args, "--resume")
    assert result.exit_code == 0, result.output[-3000:]
    assert json.loads((out / "matrix.json").read_text())["config"]["environment"] == {}


def test_the_recorded_environment_takes_the_settings_dot_env_and_lets_the_environment_override_it(
        tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / ".env").write_text("HANDLOOP_REVIEW_CAPACITY_PER_ROUND=500\nHANDLOOP_NETS_CONFIG=tiny\n"
                                   "HANDLOOP_DATABASE_URL=postgresql://u:p@h/db\n")
    monkeypatch.setenv("HANDLOOP_NETS_CONFIG", "cpu-small")
    assert sim_matrix.loop_environment() == {"nets_config": "cpu-small", "review_capacity_per_round": "500"}


def test_a_stopped_run_counts_in_its_cell(fakes, tmp_path, monkeypatch):
    def stopped(capture, work, plan, *, detector, annotator, reviewer, label, leave):
        summary = fake_summary(annotator.seed, annotator)
        summary.update(rounds=summary["rounds"][:1], rounds_completed=0, dataset_size=10, human_hours=0.1,
                       labels_per_human_hour=100.0, auto_accept_precision=None,
                       stopped={"round": 1, "reason": "cannot launch a round yet"})
        return summary

    monkeypatch.setattr(sim, "simulate", stopped)
    result = _invoke("--cells", "640-default-proposals", "--seeds", "11", "--out", str(tmp_path / "m"))
    assert result.exit_code == 0, result.output[-3000:]
    cell = json.loads(result.stdout.strip().splitlines()[-1])["cells"][0]
    assert cell["stopped"] == 1 and cell["heuristic_share_by_round_2"]["median"] is None
    assert cell["labels_per_human_hour_by_round_2"] == {"median": None, "worst": None}
    assert cell["additions_grow"] is None and not cell["targets_met"]["additions_grow"]
    assert "| 640-default-proposals | 1 (1) | 100.0 / 100.0 | - / - | - / - | - / - | 10 |" in result.stdout


def test_additions_grow_round_on_round_from_round_1():
    assert sim_matrix.additions_grow([10, 20, 20, 30]) is True
    assert sim_matrix.additions_grow([10, 40, 30]) is False
    assert sim_matrix.additions_grow([66, 9, 12]) is True  # round 0's bulk (the detector's) is not the bar
    assert sim_matrix.additions_grow([66, 9, 12, 11]) is False
    assert sim_matrix.additions_grow([10, 20]) is None and sim_matrix.additions_grow([10]) is None


def test_the_matrix_refuses_bad_options(fakes, tmp_path, monkeypatch):
    for args, message in ((["--cells", "320-default"], "unknown cells ['320-default']"),
                          (["--seeds", "1,x"], "seeds must be integers"),
                          (["--seeds", "1,1"], "distinct"),
                          (["--rounds", "11"], "rounds must be in 0..10"),
                          (["--detector", "maybe"], "detector must be on or off")):
        result = _invoke(*args, "--out", str(tmp_path / "never"))
        assert result.exit_code == 2 and message in result.output, (args, result.output)
    assert not (tmp_path / "never").exists()
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "matrix.json").write_text("{")
    result = _invoke("--out", str(bad), "--resume")
    assert result.exit_code == 2 and "is not a sim-matrix results file" in result.output
    monkeypatch.setattr(sim_matrix.preannotation, "detector_problem", lambda: "the palm model file is missing")
    result = _invoke("--out", str(tmp_path / "never"))
    assert result.exit_code == 2 and "the palm model file is missing (or pass --detector off)" in result.output
    assert not (tmp_path / "never").exists()


def test_no_test_uses_the_matrix_s_unseen_seeds():
    """The matrix judges the loop on seeds no one tuned on: no test may synthesise or simulate with them."""
    root = Path(__file__).resolve().parents[2]
    pattern = re.compile(r"\b(" + "|".join(str(s) for s in sim_matrix.UNSEEN_SEEDS) + r")\b")
    used = [f"{path.relative_to(root)}: {m.group(0)}" for path in root.rglob("*.py")
            for m in pattern.finditer(path.read_text(errors="replace"))]
    assert used == []
    assert not set(SEEDS) & set(sim_matrix.UNSEEN_SEEDS) and sim.SEED not in sim_matrix.UNSEEN_SEEDS


@pytest.mark.slow
def test_a_reduced_matrix_runs_through_the_real_stack(tmp_path, monkeypatch):
    """One cell, one seed, bench sim's --quick plan (tiny networks, 2 training steps, no detector): checks only that
    the matrix drives a real simulation to its table, plot and JSON line."""
    monkeypatch.setenv("HANDLOOP_DATA_DIR", str(tmp_path / "data"))
    get_settings.cache_clear()
    try:
        result = _invoke("--quick", "--cells", "320-default-no-proposals", "--seeds", "31", "--detector", "off",
                         "--train-steps", "2", "--handsegnet-steps", "2", "--out", str(tmp_path / "m"))
    finally:
        get_settings.cache_clear()
    assert result.exit_code == 0, result.output[-3000:]
    record = json.loads(result.stdout.strip().splitlines()[-1])
    (run,) = record["runs"]
    assert run["cell"] == "320-default-no-proposals" and run["seed"] == 31 and run["bookkeeping_ok"]
    assert run["dataset_size"] == sum(run["additions"]) and len(run["additions"]) in (1, 2)  # D_0 (and round 1)
    assert (Path(run["work_dir"]) / "simulation.json").exists()
    assert record["cells"][0]["runs"] == 1 and Path(record["plot"]).exists()
