"""The Celery side of the job hand-off, importable without torch: configuration shared by the API and the
workers, task names, and `CeleryJobQueue`, which sends committed jobs to the broker by task name.

Two brokers, one code path (docs/deployment.md):
- embedded (HANDLOOP_BROKER_URL unset): kombu's filesystem transport under <data_dir>/broker, no server, with
  whole-file writes (broker.embedded);
- distributed: Redis (HANDLOOP_BROKER_URL=redis://...), with a visibility timeout above the longest task so
  that a task whose worker died is delivered again.
Job state and progress live in the database (services.jobs.jobs); Celery's result backend only serves chords.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from celery import Celery
from kombu import Exchange, Queue
from sqlalchemy import update

from backend.broker import embedded
from backend.broker.outbox import redispatch
from backend.models.jobs import Job
from backend.services.errors import ServiceUnavailableError
from backend.settings import Settings

logger = logging.getLogger(__name__)

QUEUE_CPU = "cpu"
QUEUE_GPU = "gpu"
QUEUES = (QUEUE_CPU, QUEUE_GPU)

# Explicit task names: the API sends by name and never imports the task code (nor torch).
TASK_FIT = "handloop.fit"
TASK_FIT_BATCH = "handloop.fit_batch"
TASK_TRAIN_HANDSEGNET = "handloop.train_handsegnet"
TASK_TRAIN_MVNET = "handloop.train_mvnet"
TASK_PREDICT = "handloop.predict_batch"
TASK_HEURISTIC = "handloop.heuristic"
TASK_REVIEW_QUEUE = "handloop.build_review_queue"
TASK_ROUND = "handloop.round"
TASK_ROUND_INFERENCE = "handloop.round_inference"
TASK_ROUND_FINISH = "handloop.round_finish"
TASK_PREANNOTATE = "handloop.preannotate"
TASK_EXPORT = "handloop.export_freihand"

# Where each task runs: training and inference on the gpu queue, fitting and orchestration on cpu.
ROUTES: dict[str, str] = {
    TASK_FIT: QUEUE_CPU, TASK_FIT_BATCH: QUEUE_CPU, TASK_HEURISTIC: QUEUE_CPU, TASK_REVIEW_QUEUE: QUEUE_CPU,
    TASK_ROUND: QUEUE_CPU, TASK_ROUND_INFERENCE: QUEUE_CPU, TASK_ROUND_FINISH: QUEUE_CPU,
    TASK_TRAIN_HANDSEGNET: QUEUE_GPU, TASK_TRAIN_MVNET: QUEUE_GPU, TASK_PREDICT: QUEUE_GPU,
    TASK_PREANNOTATE: QUEUE_CPU,  # the detector runs on a CPU (ai-edge-litert), and so do the fits
    TASK_EXPORT: QUEUE_CPU,
}


def task_for_job(kind: str, payload: dict[str, Any] | None = None) -> str | None:
    """The task that runs a job row of this kind (None: no worker task for it)."""
    if kind == "fit":
        return TASK_FIT
    if kind == "round":
        return TASK_ROUND
    if kind == "predict":
        return TASK_PREDICT
    if kind == "train":
        return TASK_TRAIN_MVNET if (payload or {}).get("net") == "mvnet" else TASK_TRAIN_HANDSEGNET
    if kind == "preannotate":
        return TASK_PREANNOTATE
    if kind == "export":
        return TASK_EXPORT
    return None


def is_embedded(settings: Settings) -> bool:
    return not settings.broker_url


def embedded_folders(settings: Settings) -> dict[str, Path]:
    root = settings.broker_dir.resolve()
    return {"messages": root / "messages", "claimed": root / "claimed", "rejected": root / "rejected",
            "control": root / "control", "results": root / "results"}


def broker_url(settings: Settings) -> str:
    return settings.broker_url or "filesystem://"


def result_backend_url(settings: Settings) -> str:
    if settings.result_backend_url:
        return settings.result_backend_url
    if settings.broker_url and settings.broker_url.startswith(("redis://", "rediss://")):
        return settings.broker_url
    return f"{embedded.RESULT_BACKEND}+file://{embedded_folders(settings)['results']}"


def broker_transport_options(settings: Settings) -> dict[str, Any]:
    if is_embedded(settings):
        folders = embedded_folders(settings)
        return {"data_folder_in": str(folders["messages"]), "data_folder_out": str(folders["messages"]),
                "claimed_folder": str(folders["claimed"]), "rejected_folder": str(folders["rejected"]),
                "control_folder": str(folders["control"]),
                # The filesystem transport polls; a short interval keeps a fit's queueing delay small.
                "polling_interval": 0.1}
    options: dict[str, Any] = {
        "visibility_timeout": settings.broker_visibility_timeout_s,
        "socket_connect_timeout": 2.0,
        "socket_timeout": 10.0,
        # Restore unacknowledged messages of dead workers promptly once their visibility timeout is over.
        "unacked_restore_interval": min(10, max(1, settings.broker_visibility_timeout_s // 4)),
        "unacked_restore_throttle": 1,
    }
    if settings.broker_prefix:
        options["global_keyprefix"] = settings.broker_prefix
    return options


def ensure_embedded_folders(settings: Settings) -> None:
    if is_embedded(settings):
        for folder in embedded_folders(settings).values():
            folder.mkdir(parents=True, exist_ok=True)


def celery_config(settings: Settings) -> dict[str, Any]:
    """Configuration of every Celery app of this deployment (API client and workers alike)."""
    options = broker_transport_options(settings)
    soft = max(1, int(settings.task_time_limit_s * 0.9))
    config: dict[str, Any] = {
        "broker_url": broker_url(settings),
        # Embedded: kombu's filesystem transport with whole-file writes (broker.embedded).
        "broker_transport": embedded.TRANSPORT if is_embedded(settings) else None,
        "result_backend": result_backend_url(settings),
        "broker_transport_options": options,
        "result_backend_transport_options": {k: v for k, v in options.items()
                                             if k in ("global_keyprefix", "socket_connect_timeout", "socket_timeout")},
        "broker_connection_timeout": 2.0,
        "broker_connection_retry_on_startup": True,
        "broker_connection_max_retries": None,  # a worker waits for its broker forever
        # Each queue its own direct exchange: with Celery's defaults every queue would bind the default
        # exchange under the default routing key, and one message would reach both queues.
        "task_queues": tuple(Queue(name, Exchange(name, type="direct"), routing_key=name) for name in QUEUES),
        "task_default_exchange": QUEUE_CPU,
        "task_default_routing_key": QUEUE_CPU,
        "task_default_queue": QUEUE_CPU,  # Celery's own helpers (chord_unlock) run on cpu
        "task_routes": {name: {"queue": queue} for name, queue in ROUTES.items()},
        "task_serializer": "json",
        "result_serializer": "json",
        "accept_content": ["json"],
        # Robustness: acknowledge after the task, requeue when its process dies, one message at a time.
        "task_acks_late": True,
        "task_reject_on_worker_lost": True,
        "worker_prefetch_multiplier": 1,
        "task_time_limit": settings.task_time_limit_s,
        "task_soft_time_limit": soft,
        "result_expires": 24 * 3600,
        "task_track_started": False,
        "worker_send_task_events": False,
        "worker_hijack_root_logger": False,
        "worker_redirect_stdouts": False,
        "worker_cancel_long_running_tasks_on_connection_loss": False,
        "broker_channel_error_retry": True,
    }
    return config


def make_client_app(settings: Settings) -> Celery:
    """A Celery app without tasks: it only sends them by name (the API process)."""
    ensure_embedded_folders(settings)
    app = Celery("handloop-client", set_as_current=False)
    app.conf.update(celery_config(settings))
    return app


class CeleryJobQueue:
    """`services.jobs.jobs.JobQueue` on Celery.

    - `ensure_available` pings the broker (trusting a success for `broker_check_cache_s`) before a request
      writes a job: an unreachable broker is a 503 that writes nothing.
    - `enqueue` runs after the commit and never raises: if the send fails, the job's `dispatched_at` is
      cleared and the outbox thread (`start`) re-sends it once the broker is back.
    - `revoke` is cooperative: tasks read the 'cancelled' row before and while they work.
    """

    def __init__(self, settings: Settings, app: Celery | None = None) -> None:
        self.settings = settings
        self.app = app or make_client_app(settings)
        self._ok_until = 0.0
        self._lock = threading.Lock()
        self._session_factory: Any = None
        self._outbox: threading.Thread | None = None
        self._stop = threading.Event()
        self._fit_sender: BatchingSender | None = None

    # -- JobQueue ------------------------------------------------------------------------------------
    def ensure_available(self) -> None:
        if is_embedded(self.settings):
            return  # files on the local disk: the same disk the database write needs
        if time.monotonic() < self._ok_until:
            return
        try:
            with self.app.connection_for_write() as conn:
                conn.ensure_connection(max_retries=1, interval_start=0, interval_step=0.1, interval_max=0.1)
        except Exception as exc:
            self._ok_until = 0.0
            logger.warning("broker unreachable: %s", exc)
            raise ServiceUnavailableError(
                f"the job broker at {_redact(broker_url(self.settings))} is unreachable ({exc.__class__.__name__}); "
                "nothing was written, retry in a moment") from None
        self._ok_until = time.monotonic() + self.settings.broker_check_cache_s

    def enqueue(self, job_id: int, kind: str, payload: dict[str, Any] | None = None) -> None:
        if kind == "fit" and self._fit_sender is not None:
            self._fit_sender.put(job_id)  # sent with others by the sender thread: off the request's path
            return
        if not self.send(job_id, kind, payload):
            self._ok_until = 0.0
            self._mark_undispatched(job_id)

    def revoke(self, job_id: int) -> None:
        logger.info("job %s cancelled; its task stops when it next reads the job row", job_id)

    # -- sending -------------------------------------------------------------------------------------
    def send(self, job_id: int, kind: str, payload: dict[str, Any] | None = None) -> bool:
        """Send the task of one job; False (logged) when the broker refused or is unreachable."""
        name = task_for_job(kind, payload)
        if name is None:
            logger.warning("job %s of kind %r has no worker task; left queued", job_id, kind)
            return True
        try:
            self.app.send_task(name, args=[job_id], queue=ROUTES[name], retry=True,
                               retry_policy={"max_retries": 1, "interval_start": 0, "interval_step": 0.2})
        except Exception as exc:  # kombu raises OperationalError and friends; never fail the request
            logger.warning("job %s not handed to the broker (%s); the outbox will re-send it", job_id, exc)
            return False
        return True

    def send_fits(self, job_ids: list[int]) -> bool:
        """One `handloop.fit` message for several fit jobs (the worker fits them as one batch); False (logged)
        when the broker refused or is unreachable."""
        try:
            self.app.send_task(TASK_FIT, args=[job_ids], queue=ROUTES[TASK_FIT], retry=True,
                               retry_policy={"max_retries": 1, "interval_start": 0, "interval_step": 0.2})
        except Exception as exc:  # as in send
            logger.warning("fit jobs %s not handed to the broker (%s); the outbox will re-send them", job_ids, exc)
            return False
        return True

    def _fits_not_sent(self, job_ids: list[int]) -> None:
        self._ok_until = 0.0
        for job_id in job_ids:
            self._mark_undispatched(job_id)

    def _mark_undispatched(self, job_id: int) -> None:
        if self._session_factory is None:
            return  # no outbox bound: the job is re-sent after job_redispatch_after_s by any outbox
        try:
            with self._session_factory.begin() as session:
                session.execute(update(Job).where(Job.id == job_id).values(dispatched_at=None,
                                                                          updated_at=Job.updated_at))
        except Exception as exc:
            logger.warning("could not mark job %s for re-sending (%s); the stale-job sweep will", job_id, exc)

    # -- outbox --------------------------------------------------------------------------------------
    def start(self, session_factory: Any) -> None:
        """Bind the database and start the outbox thread (the app's lifespan calls this)."""
        self._session_factory = session_factory
        if self._outbox is not None:
            return
        self._stop.clear()
        self._outbox = threading.Thread(target=self._run_outbox, name="handloop-outbox", daemon=True)
        self._outbox.start()
        self._fit_sender = BatchingSender(self.send_fits, self._fits_not_sent, self.settings.fit_batch_size,
                                          self.settings.fit_dispatch_linger_s)

    def stop(self) -> None:
        self._stop.set()
        if self._fit_sender is not None:
            self._fit_sender.close()  # sends what is still buffered
            self._fit_sender = None
        if self._outbox is not None:
            self._outbox.join(timeout=10)
            self._outbox = None

    def _run_outbox(self) -> None:
        while not self._stop.wait(self.settings.outbox_poll_s):
            try:
                sent = redispatch(self._session_factory, self.send, self.settings)
                if sent:
                    logger.info("outbox: re-sent %d job(s)", sent)
            except Exception as exc:  # keep the thread alive through database or broker outages
                logger.warning("outbox pass failed: %s", exc)


class BatchingSender:
    """A thread that hands fit jobs to the broker several per message.

    Publishing one Celery message costs the API process about 2 ms of CPU (measured: the probe in
    docs/benchmarks.md, `api`), as much as the rest of a submission; annotators' fits arrive many per second
    at scale, and the worker fits a batch as one optimisation anyway. So `put` only buffers the id; the thread
    waits up to `linger_s` for more (at most `max_batch`), then sends them as one message. A failed send is
    reported to `on_failure` (the jobs go back to the outbox)."""

    def __init__(self, send: Callable[[list[int]], bool], on_failure: Callable[[list[int]], None], max_batch: int,
                 linger_s: float) -> None:
        self._send, self._on_failure = send, on_failure
        self._max_batch, self._linger_s = max(1, max_batch), linger_s
        self._pending: queue.SimpleQueue[int | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name="handloop-fit-sender", daemon=True)
        self._thread.start()

    def put(self, job_id: int) -> None:
        self._pending.put(job_id)

    def close(self, timeout_s: float = 10.0) -> None:
        self._pending.put(None)
        self._thread.join(timeout=timeout_s)

    def _run(self) -> None:
        closing = False
        while not closing:
            first = self._pending.get()
            if first is None:
                return
            batch, deadline = [first], time.monotonic() + self._linger_s
            while len(batch) < self._max_batch:
                try:
                    job_id = self._pending.get(timeout=max(0.0, deadline - time.monotonic()))
                except queue.Empty:
                    break
                if job_id is None:
                    closing = True
                    break
                batch.append(job_id)
            try:
                if not self._send(batch):
                    self._on_failure(batch)
            except Exception:  # keep sending later jobs; these are left to the outbox
                logger.exception("fit jobs %s: hand-off failed", batch)


def _redact(url: str) -> str:
    """A URL without its password, for messages."""
    if "@" in url and "://" in url:
        scheme, rest = url.split("://", 1)
        return f"{scheme}://***@{rest.split('@', 1)[1]}"
    return url
