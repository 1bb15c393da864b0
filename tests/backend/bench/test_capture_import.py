"""`handloop bench import` runs end to end (on a reduced size) and prints its JSON record last."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from backend.cli.main import app
from tests.support.requirements import missing


def test_bench_import_prints_json_last(monkeypatch) -> None:
    import backend.bench.capture_import as bench

    monkeypatch.setattr(bench, "SIZES", {True: (3, 4), False: (3, 4)})
    monkeypatch.setattr(bench, "WIDTH", 256)
    monkeypatch.setattr(bench, "HEIGHT", 192)
    result = CliRunner().invoke(app, ["bench", "import", "--json", "--quick", "--workers", "1", "--no-ui"])
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout.strip().splitlines()[-1])
    assert record["benchmark"] == "import" and record["frames"] == 4 and record["cameras"] == 3
    assert record["views_imported"] == 12 and record["image_px"] == [256, 192]
    assert [m["frames"] for m in record["memory_vs_frames"]] == [1, 2, 3, 4]
    assert record["end_to_end_frames_per_s"] > 0 and record["assemble_peak_pss_mb"] > 0
    assert record["annotate_interactive_ms"] is None and record["annotate_page"] is None


def test_bench_import_times_the_annotate_page_at_the_working_width_and_at_full_resolution(monkeypatch) -> None:
    import backend.bench.capture_import as bench
    from backend.bench.import_ui import CHROMIUM

    if not Path(CHROMIUM).exists():
        message = f"Chromium is not installed at {CHROMIUM}"
        missing(message, needed_by="the browser step")
    monkeypatch.setattr(bench, "SIZES", {True: (2, 2), False: (2, 2)})
    monkeypatch.setattr(bench, "WIDTH", 256)
    monkeypatch.setattr(bench, "HEIGHT", 192)
    result = CliRunner().invoke(app, ["bench", "import", "--json", "--quick", "--workers", "1", "--ui-repeats", "1",
                                      "--working-width", "128"])
    assert result.exit_code == 0, result.output
    page = json.loads(result.stdout.strip().splitlines()[-1])["annotate_page"]
    # The page drew working-width copies for the 256 px views, then the originals once the width was cleared.
    assert page["at_working_width"]["image_px"] == [128, 96] and page["at_working_width"]["view_px"] == [256, 192]
    assert page["at_full_resolution"]["image_px"] == [256, 192]
    assert page["interactive_ms"] == page["at_working_width"]["interactive_ms"] > 0
