"""`handloop bench detect`: the issue's keys as the last stdout line; a clear error without the model files."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

KEYS = ("kp2d_median_px", "kp2d_p90_px", "kp2d_median_frac", "detection_rate", "kp3d_median_mm", "kp3d_mean_mm",
        "fit_vertex_median_mm", "s_per_frame")


@pytest.mark.slow
@pytest.mark.usefixtures("require_detector")
def test_bench_detect_reports_every_key(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    from backend.bench.detect import run
    from backend.simulation.reviewer import ReviewerConfig

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the capture cache goes to the test's folder
    record = run(quick=True, frames_per_sequence=1)
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert printed["benchmark"] == "detect"
    for key in KEYS:
        assert isinstance(printed[key], float) and math.isfinite(printed[key]), key
    assert 0 < record["detection_rate"] <= 1 and record["fits"] >= 1
    assert printed["reviewer_bar_mm"] == ReviewerConfig().accept_below_mm
    assert 0 <= printed["fit_vertex_within_reviewer_bar"] <= 1
    # Detections on the rendered hand are not noise: a few px at 320 px, millimetres in 3D.
    assert record["kp2d_median_frac"] < 0.3 and record["kp3d_median_mm"] < 40
    assert (tmp_path / "handloop-bench-cache").is_dir()
    # The detector's heuristic judged every fit as the worker does; its counts add up.
    h = printed["detector_heuristic"]
    assert h["fits"] == record["fits"] and 0 <= h["accepted"] <= h["fits"]
    assert 0 <= h["accepted_over_10mm"] <= h["accepted_over_8mm"] <= h["accepted"]
    assert (h["accepted_vertex_mean_mm"] is None) == (h["accepted"] == 0)
    assert printed["settings"]["detector_heuristic_thresholds"]["max_mean_distance_m"] == 0.010


def test_bench_detect_without_model_files_is_a_clear_error(tmp_path: Path) -> None:
    code = ("import os, sys; os.environ['HANDLOOP_DETECTOR_DIR'] = sys.argv[1]; "
            "from backend.cli.main import app; "
            "app(prog_name='handloop', args=['bench', 'detect', '--json', '--quick'])")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True)
    assert out.returncode == 2
    assert "bench detect needs the detector" in out.stderr and "is missing" in out.stderr
    assert not out.stdout.strip()  # no record of a run that did not happen


def test_bench_detect_fits_as_round_0s_fit_jobs_do() -> None:
    from types import SimpleNamespace

    from backend.bench.detect import round0_fit_config
    from backend.settings import get_settings
    from workers.fitting.config import LossWeights
    from workers.tasks.fits import fit_config

    # The same weights and solver schedule as a fit job of a detector's frame with masks: the benchmark's fit
    # error is what users get from round 0.
    assert round0_fit_config() == fit_config(SimpleNamespace(settings=get_settings()), "detector", with_masks=True)
    assert round0_fit_config().weights == LossWeights.detector_with_silhouettes()
