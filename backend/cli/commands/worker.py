"""`handloop worker`: a Celery worker for the job queues (cpu: fits and round orchestration; gpu: training
and inference). Settings from HANDLOOP_* (HANDLOOP_BROKER_URL for a Redis broker, unset for the embedded
one; HANDLOOP_DATABASE_URL; HANDLOOP_DATA_DIR on storage shared with the API)."""

from __future__ import annotations

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @app.command("worker")
    def worker(
        queues: str = typer.Option("cpu,gpu", "--queues", "-Q", help="Comma-separated queues to consume: cpu, gpu."),
        concurrency: int | None = typer.Option(None, "--concurrency", "-c", min=1, max=256,
                                               help="Worker processes (default HANDLOOP_WORKER_CONCURRENCY, 1)."),
        hostname: str | None = typer.Option(None, "--hostname", "-n", help="Worker name, e.g. gpu1@%h."),
        loglevel: str = typer.Option("info", "--loglevel", "-l", help="debug, info, warning or error."),
    ) -> None:
        """Run a worker process (prefork pool; one task at a time per process, acknowledged when done)."""
        from backend.broker.celery_queue import QUEUES
        from backend.settings import get_settings

        names = [q.strip() for q in queues.split(",") if q.strip()]
        unknown = sorted(set(names) - set(QUEUES))
        if not names or unknown:
            raise typer.BadParameter(f"queues must be among {list(QUEUES)}; got {queues!r}", param_hint="--queues")
        settings = get_settings()
        from workers.tasks.app import celery_app

        argv = ["worker", f"--queues={','.join(names)}", f"--concurrency={concurrency or settings.worker_concurrency}",
                f"--loglevel={loglevel}", "--pool=prefork", "--without-gossip", "--without-mingle",
                "--without-heartbeat"]
        if hostname:
            argv.append(f"--hostname={hostname}")
        celery_app.worker_main(argv)
