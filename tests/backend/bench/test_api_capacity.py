"""`handloop bench api`: its modes' options, the CPU meter's /proc reading (backends that exit in the window
included), the seed's statistics, and short probes end to end on SQLite and PostgreSQL (a real uvicorn server;
correctness keys checked, no figure asserted)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest
from typer.testing import CliRunner

from backend.bench.api_capacity import CpuMeter, _cpu_ticks, _descendants
from backend.cli.main import app


@pytest.mark.parametrize(("args", "message"), [
    (["--database", "mysql"], "postgres, sqlite"),
    (["--probe", "--crowd", "5"], "choose one"),
    (["--db-pool", "0"], "--db-pool"),
])
def test_bad_options_are_refused_naming_the_problem(args, message) -> None:
    result = CliRunner().invoke(app, ["bench", "api", "--json", *args])
    assert result.exit_code != 0
    assert message in " ".join(result.output.replace("│", " ").split())  # the error box wraps long lines


def test_the_meter_counts_a_child_process_s_cpu() -> None:
    assert _cpu_ticks(os.getpid()) is not None and _cpu_ticks(2**22 + 12345) is None
    busy = ("import sys, time\nend = time.process_time() + 0.3\nwhile time.process_time() < end: pass\n"
            "sys.stdin.read()")
    child = subprocess.Popen([sys.executable, "-c", busy], stdin=subprocess.PIPE)
    try:
        assert child.pid in _descendants(os.getpid())
        meter = CpuMeter(child.pid)  # the child's tree only
        meter.start()
        while (_cpu_ticks(child.pid) or 0) / os.sysconf("SC_CLK_TCK") < 0.3:
            time.sleep(0.01)  # until the child has burnt its 0.3 s
        meter.stop()
        assert meter.server_s > 0.1  # counted from start(): most of the child's 0.3 s (it starts up first)
        assert meter.db_s == 0.0  # no database backends given
    finally:
        child.communicate(b"")


def test_the_meter_counts_a_backend_that_exits_in_the_window_from_what_its_parent_reaped() -> None:
    # A stand-in postmaster: one long-lived child (a backend connected all along) and, on a line from us, a
    # short-lived one that burns 0.3 s of CPU and exits (an overflow connection closed), which it waits for.
    postmaster = ("import subprocess, sys\n"
                  "wait = [sys.executable, '-c', 'import sys; sys.stdin.read()']\n"
                  "idle = subprocess.Popen(wait, stdin=subprocess.PIPE)\n"
                  "print(idle.pid, flush=True)\n"
                  "sys.stdin.readline()\n"
                  "burn = 'import time\\nend = time.process_time() + 0.3\\nwhile time.process_time() < end: pass'\n"
                  "subprocess.run([sys.executable, '-c', burn], check=True)\n"
                  "print('reaped', flush=True)\n"
                  "sys.stdin.readline()\n"
                  "idle.communicate(b'')\n")
    parent = subprocess.Popen([sys.executable, "-c", postmaster], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    server = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        backend = int(parent.stdout.readline())
        meter = CpuMeter(server.pid, backend_pids=lambda: [backend])
        meter.start()
        parent.stdin.write("go\n")
        parent.stdin.flush()
        assert parent.stdout.readline().strip() == "reaped"
        meter.stop()
        assert meter.db_s > 0.25  # the exited child's 0.3 s, though it was never among the backends listed
        assert meter.machine_s >= meter.db_s - 0.05  # the machine-wide check saw it too
    finally:
        parent.communicate("\n")
        server.communicate(b"")


def test_probe_on_sqlite_runs_end_to_end_and_checks_what_it_served(tmp_path) -> None:
    result = CliRunner().invoke(app, ["bench", "api", "--json", "--probe", "--database", "sqlite", "--seconds", "2",
                                      "--db-pool", "3"])
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout.strip().splitlines()[-1])
    assert record["benchmark"] == "api" and record["run"] == "probe" and record["database"] == "sqlite"
    assert record["settings"]["annotators"] == 1 and record["settings"]["server_workers"] == 1
    assert record["settings"]["db_pool"] == 3 and "db pool 3+0 per worker" in record["server"]  # a fixed pool
    assert record["duplicate_assignments"] == 0 and record["lost_submissions"] == 0 and record["errors"] == {}
    assert record["db_cpu_ms_per_cycle"] is None and record["db_sessions_opened"] is None  # SQLite: in the server
    if record["submits"]:
        assert record["cpu_ms_per_cycle"] == record["server_cpu_ms_per_cycle"] > 0
    for key in ("p99_ms_next", "p99_ms_submit", "submits_per_s", "load_average_1min", "machine_cpu_ms_per_cycle"):
        assert key in record


def test_run_refuses_an_empty_pool_before_creating_anything(tmp_path, monkeypatch) -> None:
    from backend.bench.api_capacity import run

    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))
    with pytest.raises(ValueError, match="db_pool must be at least 1"):
        run(1, 1.0, database="sqlite", db_pool=0)
    assert list(tmp_path.iterdir()) == []  # no data folder made


@pytest.mark.postgres
def test_seeding_analyzes_only_the_filled_tables(pg_url) -> None:
    # An analyzed empty table reads to PostgreSQL as truly empty: the foreign-key checks' cached plans would scan
    # the submissions sequentially while the run fills them (backend/bench/api_capacity.py, _analyze_seeded_tables).
    from sqlalchemy import create_engine, text

    from backend.bench.api_capacity import _seed

    _seed(pg_url, annotators=2, samples=50, cameras=2, width=64)
    engine = create_engine(pg_url)
    try:
        with engine.connect() as conn:
            tuples = dict(conn.execute(text("SELECT relname, reltuples FROM pg_class WHERE oid = ANY(ARRAY["
                                            "'samples', 'views', 'submissions', 'clicks', 'jobs']::regclass[])")).all())
    finally:
        engine.dispose()
    assert tuples["samples"] >= 50 and tuples["views"] >= 100  # analyzed (the template's rows included)
    assert tuples["submissions"] == tuples["clicks"] == tuples["jobs"] == -1  # never analyzed


@pytest.mark.postgres
def test_probe_on_postgres_meters_the_database_backends(pg_template) -> None:
    result = CliRunner().invoke(app, ["bench", "api", "--json", "--probe", "--seconds", "2"])
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout.strip().splitlines()[-1])
    assert record["database"] == "postgresql" and record["errors"] == {}
    assert record["duplicate_assignments"] == 0 and record["lost_submissions"] == 0
    assert record["db_sessions_opened"] is not None and record["db_sessions_opened"] >= 0
    if record["submits"]:
        assert record["db_cpu_ms_per_cycle"] is not None and record["db_cpu_ms_per_cycle"] >= 0
        assert record["cpu_ms_per_cycle"] >= record["server_cpu_ms_per_cycle"]
