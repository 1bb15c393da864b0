"""`handloop bench api`: annotator throughput, latency and CPU per cycle against PostgreSQL or SQLite
(backend/bench/api_capacity.py)."""

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
        probe: bool = typer.Option(False, "--probe", help="The per-cycle CPU probe: one annotator, one server "
                                   "worker, saturated, 10 s (cpu_ms_per_cycle, server_ and db_cpu_ms_per_cycle)."),
        crowd: int = typer.Option(0, "--crowd", min=0, max=20_000, help="N annotators at a human pace, one "
                                  "cycle per 20 s each (N / 20 submissions/s offered), 40 s measured."),
        database: str = typer.Option("postgres", "--database", help="postgres (with the Redis broker) or sqlite "
                                     "(the embedded database and broker)."),
        annotators: int = typer.Option(50, min=1, max=20_000),
        seconds: float = typer.Option(None, min=1, max=3600, help="Measured seconds (default: 30; probe 10; "
                                      "crowd 40)."),
        rate: float = typer.Option(200.0, min=0, max=100_000, help="Offered submissions/s in total, each annotator "
                                   "on a fixed schedule; 0 saturates (every annotator as fast as it can)."),
        server_workers: int = typer.Option(2, min=1, max=64, help="uvicorn worker processes."),
        db_pool: int | None = typer.Option(None, "--db-pool", min=1, max=200, help="A fixed pool of this many database "
                                    "connections per server worker (default: the server's own, "
                                    "HANDLOOP_DB_POOL_SIZE and HANDLOOP_DB_MAX_OVERFLOW's defaults)."),
        cameras: int = typer.Option(8, min=1, max=64, help="Views per sample (6 clicks each)."),
        pg_url: str = typer.Option("postgresql+psycopg://postgres@127.0.0.1:5432/postgres",
                                   help="Maintenance database URL; a fresh database is created beside it."),
        broker_url: str = typer.Option("redis://127.0.0.1:6379/15", help="The scale-out broker receiving the fit "
                                       "jobs (under a key prefix of the run's own, removed afterwards)."),
    ) -> None:
        """50 simulated annotators doing next -> submit over loopback for 30 s on PostgreSQL and Redis."""
        from backend.bench.api_capacity import CROWD_CYCLE_S, DATABASES, run
        from backend.bench.common import emit

        if database not in DATABASES:
            raise typer.BadParameter(f"one of {', '.join(DATABASES)}, not {database!r}", param_hint="--database")
        if probe and crowd:
            raise typer.BadParameter("--probe and --crowd are different runs; choose one", param_hint="--probe")
        logging.getLogger("httpx").setLevel(logging.WARNING)  # one line per request would drown the progress
        mode = "probe" if probe else "crowd" if crowd else "saturated" if rate == 0 else "paced"
        if probe:
            annotators, server_workers, rate, seconds = 1, 1, 0.0, seconds or 10.0
        elif crowd:
            annotators, rate, seconds = crowd, crowd / CROWD_CYCLE_S, seconds or 2 * CROWD_CYCLE_S
        seconds = seconds or 30.0
        if quick:  # the same load per annotator
            rate, annotators, seconds = rate * min(annotators, 10) / annotators, min(annotators, 10), min(seconds, 5.0)
        started = time.perf_counter()
        result = run(annotators, seconds, rate=rate, cameras=cameras, server_workers=server_workers,
                     database=database, pg_admin_url=pg_url, broker_url=broker_url, db_pool=db_pool)
        logger.info("api bench: %s", json.dumps(result))
        emit("api", {"run": mode, **result},
             {"annotators": annotators, "seconds": seconds, "server_workers": server_workers, "cameras": cameras,
              "rate": rate, "db_pool": db_pool, "backend": "postgresql" if database == "postgres" else "sqlite",
              "broker": "redis" if database == "postgres" else "embedded", "quick": quick}, started)
        del json_out  # the JSON line is always the last stdout line; progress goes to stderr
