"""The workers' Celery app: `celery -A workers.tasks.app worker -Q cpu,gpu` or `handloop worker`.

Configuration comes from backend.broker.celery_queue (shared with the API's client app) and the
settings in the environment (HANDLOOP_*). Each pool process sets its torch threads and warms the
fitting code up before its first task; a ready file (HANDLOOP_WORKER_READY_FILE) tells a supervisor
(backend.runtime) that the worker consumes.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

from celery import Celery
from celery.signals import worker_process_init, worker_ready, worker_shutdown

from backend.broker.celery_queue import celery_config, ensure_embedded_folders
from backend.settings import Settings, get_settings

log = logging.getLogger(__name__)

READY_FILE_ENV = "HANDLOOP_WORKER_READY_FILE"


def create_worker_app(settings: Settings | None = None) -> Celery:
    settings = settings or get_settings()
    ensure_embedded_folders(settings)
    # every task retries a delivery for a job that may still run elsewhere (workers.tasks.recovery)
    app = Celery("handloop", set_as_current=True, task_cls="workers.tasks.recovery:JobTask")
    app.conf.update(celery_config(settings))
    app.conf.update(worker_concurrency=settings.worker_concurrency, imports=("workers.tasks.definitions",))
    return app


celery_app = create_worker_app()
app = celery_app  # `celery -A workers.tasks.app` finds it under either name


@worker_process_init.connect
def _init_process(**_: Any) -> None:
    import torch  # deferred: torch loads in each pool process, after the fork, not in the worker's main process

    torch.set_num_threads(get_settings().worker_torch_threads)


@worker_ready.connect
def _ready(**_: Any) -> None:
    path = os.environ.get(READY_FILE_ENV)
    if path:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(str(os.getpid()))
    log.info("handloop worker ready (broker %s)", celery_app.conf.broker_url.split("@")[-1])


@worker_shutdown.connect
def _shutdown(**_: Any) -> None:
    path = os.environ.get(READY_FILE_ENV)
    if path:
        Path(path).unlink(missing_ok=True)
