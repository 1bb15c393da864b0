"""`handloop bench api`: annotator throughput and latency against PostgreSQL (backend/bench/api_capacity.py)."""

from __future__ import annotations

import json
import logging
import time

import typer

logger = logging.getLogger("handloop.bench.api")


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("api")
    def bench_api(
        json_out: bool = typer.Option(False, "--json", help="Print only the JSON line on stdout."),
        quick: bool = typer.Option(False, "--quick", help="10 annotators for 5 s (smoke test)."),
        annotators: int = typer.Option(50, min=1, max=1000),
        seconds: float = typer.Option(30.0, min=1, max=3600),
        rate: float = typer.Option(200.0, min=0, max=100_000, help="Offered submissions/s in total, each annotator "
                                   "on a fixed schedule; 0 saturates (every annotator as fast as it can)."),
        server_workers: int = typer.Option(2, min=1, max=64, help="uvicorn worker processes."),
        cameras: int = typer.Option(8, min=1, max=64, help="Views per sample (6 clicks each)."),
        pg_url: str = typer.Option("postgresql+psycopg://postgres@127.0.0.1:5432/postgres",
                                   help="Maintenance database URL; a fresh database is created beside it."),
        broker_url: str = typer.Option("redis://127.0.0.1:6379/15", help="The scale-out broker receiving the fit "
                                       "jobs (under a key prefix of the run's own, removed afterwards)."),
    ) -> None:
        """50 simulated annotators doing next -> submit over loopback for 30 s on PostgreSQL and Redis."""
        from backend.bench.api_capacity import run
        from backend.bench.common import emit

        logging.getLogger("httpx").setLevel(logging.WARNING)  # one line per request would drown the progress
        if quick:  # the same load per annotator
            rate, annotators, seconds = rate * min(annotators, 10) / annotators, min(annotators, 10), min(seconds, 5.0)
        started = time.perf_counter()
        result = run(annotators, seconds, rate=rate, cameras=cameras, server_workers=server_workers,
                     pg_admin_url=pg_url, broker_url=broker_url)
        logger.info("api bench: %s", json.dumps(result))
        emit("api", result, {"annotators": annotators, "seconds": seconds, "server_workers": server_workers,
                             "cameras": cameras, "rate": rate, "backend": "postgresql", "broker": "redis",
                             "quick": quick}, started)
        del json_out  # the JSON line is always the last stdout line; progress goes to stderr
