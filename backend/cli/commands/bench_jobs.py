"""`handloop bench jobs`: fit jobs through Celery against a direct batched call of the same fits."""

from __future__ import annotations

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("jobs")
    def bench_jobs(
        json_out: bool = typer.Option(False, "--json", help="Print the JSON record as the last stdout line."),
        quick: bool = typer.Option(False, "--quick", help="Reduced run (about a minute)."),
        broker: str = typer.Option("embedded", help="embedded (filesystem transport) or redis "
                                   "(HANDLOOP_BENCH_REDIS_URL, default redis://127.0.0.1:6379/0)."),
        batch_size: int = typer.Option(6, min=1, max=64, help="Fits per batch on both paths."),
        repeats: int | None = typer.Option(None, min=1, max=20, help="Repeats (default 4, quick 2)."),
    ) -> None:
        """Throughput of fit jobs (claim, load, fit, record) on a real worker vs the same fits called directly;
        keys celery_overhead_pct, fits_per_s_celery, fits_per_s_direct."""
        if broker not in ("embedded", "redis"):
            raise typer.BadParameter("broker must be 'embedded' or 'redis'", param_hint="--broker")
        from backend.bench.job_overhead import run

        record = run(quick=quick, emit_json=json_out, broker=broker, batch_size=batch_size, repeats=repeats)
        if not json_out:
            typer.echo(f"direct {record['fits_per_s_direct']:.3f} fits/s, Celery {record['fits_per_s_celery']:.3f} "
                       f"fits/s, overhead {record['celery_overhead_pct']:.1f} %")
