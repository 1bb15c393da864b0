"""What a worker process holds on to between tasks: settings, the database, storage, the hand model, and
caches of expensive objects (fitting engines per rig and configuration, loaded networks per checkpoint)."""

from __future__ import annotations

import logging
import os
import socket
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sqlalchemy.orm import Session, sessionmaker

from backend.broker import worker_processes
from backend.broker.celery_queue import CeleryJobQueue
from backend.db.session import create_engine_from_url, make_session_factory
from backend.services.captures.storage import LocalDiskStorage, Storage
from backend.services.jobs import jobs
from backend.settings import Settings, get_settings
from workers.handmodel.loading import load_hand_model

log = logging.getLogger(__name__)


@dataclass
class WorkerContext:
    """One per worker process (`get_context`); tests build their own around a test database."""

    settings: Settings
    session_factory: sessionmaker[Session]
    storage: Storage
    job_queue: Any  # backend.services.jobs.jobs.JobQueue: where jobs created by tasks are handed over
    worker_name: str = field(default_factory=lambda: f"{socket.gethostname()}:{os.getpid()}")
    _cache: dict[Any, Any] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def cached(self, key: Any, make: Any) -> Any:
        """`make()` once per key for the life of the process."""
        with self._lock:
            if key not in self._cache:
                self._cache[key] = make()
            return self._cache[key]

    def claim(self, session: Session, job_id: int) -> Any:
        """services.jobs.jobs.claim with this worker's name and process and the configured heartbeat and attempt
        limits. Raises services.jobs.jobs.JobStillRunningError for a job that may run elsewhere: the task is then
        retried (workers.tasks.recovery)."""

        return jobs.claim(session, job_id, self.worker_name, self.settings.job_heartbeat_timeout_s,
                          max_attempts=self.settings.job_max_attempts, process=worker_processes.current())

    def storage_path(self, key: str) -> Path:
        """The file behind a storage key. Workers read images and masks as files (the networks' data code
        takes paths), so storage must be a shared filesystem in distributed mode (docs/deployment.md)."""
        if not isinstance(self.storage, LocalDiskStorage):
            raise TypeError(f"workers need file storage (LocalDiskStorage on a shared folder), not {self.storage!r}")
        return self.storage.local_path(key)

    def hand_model(self, side: str = "right") -> Any:
        """The arrays of this side's hand model ("right" or "left"; HANDLOOP_MANO_PATH, else the built-in
        hand, whose left is the mirror of its right), loaded once per process and side."""

        return load_hand_model(self.settings.mano_path, side)


_CONTEXT: WorkerContext | None = None
_CONTEXT_LOCK = threading.Lock()


def build_context(settings: Settings, job_queue: Any | None = None) -> WorkerContext:
    engine = create_engine_from_url(settings.resolved_database_url, pool_size=2, max_overflow=4)
    if job_queue is None:
        job_queue = CeleryJobQueue(settings)
    return WorkerContext(settings, make_session_factory(engine), LocalDiskStorage(settings.storage_dir), job_queue)


def get_context() -> WorkerContext:
    """The process's context, built from the environment's settings on first use."""
    global _CONTEXT
    with _CONTEXT_LOCK:
        if _CONTEXT is None:
            _CONTEXT = build_context(get_settings())
        return _CONTEXT


def set_context(context: WorkerContext | None) -> None:
    """Replace the process's context (tests, benchmarks)."""
    global _CONTEXT
    with _CONTEXT_LOCK:
        _CONTEXT = context
