"""`handloop bench import` runs end to end (on a reduced size) and prints its JSON record last."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from backend.cli.main import app


def test_bench_import_prints_json_last(monkeypatch) -> None:
    import backend.bench.capture_import as bench

    monkeypatch.setattr(bench, "SIZES", {True: (3, 4), False: (3, 4)})
    monkeypatch.setattr(bench, "WIDTH", 256)
    monkeypatch.setattr(bench, "HEIGHT", 192)
    result = CliRunner().invoke(app, ["bench", "import", "--json", "--quick", "--workers", "1"])
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout.strip().splitlines()[-1])
    assert record["benchmark"] == "import" and record["frames"] == 4 and record["cameras"] == 3
    assert record["views_imported"] == 12 and record["image_px"] == [256, 192]
    assert [m["frames"] for m in record["memory_vs_frames"]] == [1, 2, 3, 4]
    assert record["end_to_end_frames_per_s"] > 0 and record["assemble_peak_pss_mb"] > 0
