"""`handloop demo --no-serve` sets up a capture, preview, database, project and admin, and a second run
reuses them."""

from __future__ import annotations

import re

import pytest
from typer.testing import CliRunner

from backend.cli.main import app


@pytest.fixture()
def data_dir(tmp_path, monkeypatch):
    from backend.settings import get_settings

    monkeypatch.setenv("HANDLOOP_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.delenv("HANDLOOP_DATABASE_URL", raising=False)
    get_settings.cache_clear()
    yield tmp_path / "data"
    get_settings.cache_clear()


def test_demo_sets_up_everything_and_reuses_it(data_dir, monkeypatch):
    from sqlalchemy import create_engine, text

    from backend.services.rounds import preannotation
    from workers.capture import read_capture

    monkeypatch.setattr(preannotation, "quick_detector_problem", lambda: None)  # the detector installed
    monkeypatch.setattr(preannotation, "detector_problem", lambda: None)
    runner = CliRunner()
    args = ["demo", "--no-serve", "--sequences", "2", "--frames", "2", "--width", "64"]
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    assert re.search(r"round 0 : job \d+ queued", first.output), first.output  # the worker pre-annotates it
    password = re.search(r"login\s+: admin@handloop\.local / (\S+)", first.output).group(1)
    assert "stand-in for MANO" in first.output
    capture = read_capture(data_dir / "demo-capture")
    assert sum(len(s.frames) for s in capture.sequences) == 4
    assert (data_dir / "demo-preview.png").stat().st_size > 1000
    engine = create_engine(f"sqlite:///{data_dir / 'handloop.sqlite3'}")
    with engine.connect() as db:
        assert db.execute(text("select count(*) from projects where name = 'demo'")).scalar() == 1
        assert db.execute(text("select count(*) from samples where state = 'unlabeled'")).scalar() == 4
        assert db.execute(text("select kind, state from jobs")).all() == [("preannotate", "queued")]
        assert db.execute(text("select role from users where email = 'admin@handloop.local'")).scalar() == "admin"

    second = runner.invoke(app, args)
    assert second.exit_code == 0, second.output
    assert f"admin@handloop.local / {password}" in second.output
    with engine.connect() as db:
        assert db.execute(text("select count(*) from projects")).scalar() == 1
        assert db.execute(text("select count(*) from users")).scalar() == 1


@pytest.mark.parametrize("args", [["--no-preannotate"], []])
def test_demo_without_pre_annotation_queues_the_samples_for_annotation(data_dir, monkeypatch, args):
    """--no-preannotate, or no detector installed (then the demo says why): the samples go to the annotators."""
    from sqlalchemy import create_engine, text

    from backend.services.rounds import preannotation

    missing = "the hand landmark model file is missing: install it with scripts/fetch_models.sh"
    monkeypatch.setattr(preannotation, "quick_detector_problem", lambda: None if args else missing)
    result = CliRunner().invoke(app, ["demo", "--no-serve", "--sequences", "1", "--frames", "2", "--width", "64",
                                      *args])
    assert result.exit_code == 0, result.output
    assert ("round 0" not in result.output) if args else (f"pre-annotation off: {missing}" in result.output)
    engine = create_engine(f"sqlite:///{data_dir / 'handloop.sqlite3'}")
    with engine.connect() as db:
        assert db.execute(text("select state, count(*) from samples group by state")).all() == [("needs_annotation", 2)]
        assert db.execute(text("select count(*) from jobs")).scalar() == 0
    engine.dispose()
