"""Run the whole stack on this machine: the API server and a Celery worker, each its own process.

`start_stack(settings)` is what `handloop demo`, the integration tests and `handloop simulate` use:

    with start_stack(settings) as stack:
        httpx.get(stack.base_url + "/api/health")

The settings travel to both processes as HANDLOOP_* environment variables. Without HANDLOOP_BROKER_URL
(settings.broker_url) the worker uses the embedded broker (kombu's filesystem transport under the data
folder; no server needed); with it, e.g. redis://..., the same processes run in distributed mode. The
database must be migrated before (backend.db.migrate.upgrade). Logs go to <data_dir>/logs/.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from backend.broker.celery_queue import QUEUES, ensure_embedded_folders
from backend.settings import Settings

logger = logging.getLogger(__name__)

READY_FILE_ENV = "HANDLOOP_WORKER_READY_FILE"  # workers.tasks.app writes it once the worker consumes


class StackError(RuntimeError):
    """A process of the stack did not start; the message quotes the end of its log."""


def settings_env(settings: Settings) -> dict[str, str]:
    """HANDLOOP_* variables that reproduce `settings` in another process (values that are None stay unset)."""
    env: dict[str, str] = {}
    for name, value in settings.model_dump(mode="json").items():
        if value is None:
            continue
        key = f"HANDLOOP_{name.upper()}"
        env[key] = value if isinstance(value, str) else json.dumps(value)
    if settings.database_url is None:  # pin the SQLite file: the children may run elsewhere (cwd)
        env["HANDLOOP_DATABASE_URL"] = settings.resolved_database_url
    env["HANDLOOP_DATA_DIR"] = str(settings.data_dir.resolve())
    return env


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _tail(path: Path, chars: int = 3000) -> str:
    try:
        return path.read_text(errors="replace")[-chars:]
    except OSError:
        return "(no log)"


class RunningStack:
    """The API and worker processes of `start_stack`. A context manager; `stop()` ends both."""

    def __init__(self, settings: Settings, host: str, port: int, worker_queues: Sequence[str],
                 worker_concurrency: int, env: dict[str, str]) -> None:
        self.settings = settings
        self.host = host
        self.port = port
        self.base_url = f"http://{host}:{port}"
        self.worker_queues = tuple(worker_queues)
        self.worker_concurrency = worker_concurrency
        self.env = env
        self.log_dir = settings.data_dir.resolve() / "logs"
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.api: subprocess.Popen | None = None
        self.worker: subprocess.Popen | None = None
        self._ready_file: Path | None = None
        self._previous_sigterm: Any = None
        self._sigterm_trapped = False

    # -- processes -------------------------------------------------------------------------------------
    def _spawn(self, args: list[str], log_name: str, extra_env: dict[str, str] | None = None) -> subprocess.Popen:
        log = open(self.log_dir / log_name, "ab")  # noqa: SIM115 - handed to the child, closed below
        try:
            return subprocess.Popen(args, env={**self.env, **(extra_env or {})}, stdout=log, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL, start_new_session=True)
        finally:
            log.close()

    def start_api(self, timeout_s: float = 90.0) -> None:
        self.api = self._spawn([sys.executable, "-m", "uvicorn", "backend.app:create_app", "--factory", "--host",
                                self.host, "--port", str(self.port), "--log-level", "warning",
                                "--timeout-keep-alive", "30", "--no-proxy-headers"], "api.log")
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.api.poll() is not None:
                raise StackError(f"the API exited with code {self.api.returncode}:\n{_tail(self.log_dir / 'api.log')}")
            try:
                with urllib.request.urlopen(self.base_url + "/api/health", timeout=2) as response:
                    if response.status == 200:
                        return
            except (urllib.error.URLError, OSError):
                pass
            time.sleep(0.2)
        raise StackError(f"the API did not answer within {timeout_s:.0f} s:\n{_tail(self.log_dir / 'api.log')}")

    def start_worker(self, timeout_s: float = 180.0) -> None:
        """Start (or restart) the worker and wait until it consumes."""
        if self.worker is not None and self.worker.poll() is None:
            raise StackError("a worker is already running; stop or kill it first")
        self._ready_file = self.log_dir / f"worker-{uuid.uuid4().hex[:8]}.ready"
        args = [sys.executable, "-c", "from backend.cli.main import app; app(prog_name='handloop')", "worker",
                "--queues", ",".join(self.worker_queues), "--concurrency", str(self.worker_concurrency),
                "--hostname", f"stack-{uuid.uuid4().hex[:6]}@%h", "--loglevel", "info"]
        self.worker = self._spawn(args, "worker.log", {READY_FILE_ENV: str(self._ready_file)})
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.worker.poll() is not None:
                raise StackError(f"the worker exited with code {self.worker.returncode}:\n"
                                 f"{_tail(self.log_dir / 'worker.log')}")
            if self._ready_file.exists():
                return
            time.sleep(0.2)
        raise StackError(f"the worker did not get ready within {timeout_s:.0f} s:\n"
                         f"{_tail(self.log_dir / 'worker.log')}")

    def kill_worker(self) -> None:
        """SIGKILL the worker and its pool processes at once (a crash: nothing is acknowledged)."""
        if self.worker is not None and self.worker.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.worker.pid, signal.SIGKILL)
            self.worker.wait(timeout=30)

    def stop_worker(self, grace_s: float = 10.0) -> None:
        self._stop(self.worker, grace_s)

    def stop(self) -> None:
        """End the worker (warm shutdown, then kill) and the API."""
        try:
            self._stop(self.worker, 10.0)
            self._stop(self.api, 10.0)
        finally:
            if self._sigterm_trapped:
                signal.signal(signal.SIGTERM, self._previous_sigterm or signal.SIG_DFL)
                self._sigterm_trapped = False

    @staticmethod
    def _stop(process: subprocess.Popen | None, grace_s: float) -> None:
        if process is None or process.poll() is not None:
            return
        with contextlib.suppress(ProcessLookupError):
            process.send_signal(signal.SIGTERM)  # the leader only: Celery's main process stops its pool itself
        try:
            process.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=30)

    @property
    def worker_log(self) -> Path:
        return self.log_dir / "worker.log"

    @property
    def api_log(self) -> Path:
        return self.log_dir / "api.log"

    def trap_sigterm(self) -> None:
        """SIGTERM (a `kill`, a CI timeout) would end this process without running `stop()`'s callers' finally
        blocks, leaving the API and worker (in sessions of their own) running: make it a SystemExit until
        `stop()`. Only the main thread may set handlers; elsewhere the caller's own handling stands."""
        if threading.current_thread() is threading.main_thread() and not self._sigterm_trapped:
            self._previous_sigterm = signal.signal(signal.SIGTERM, _exit_on_sigterm)
            self._sigterm_trapped = True

    def __enter__(self) -> RunningStack:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()


def _exit_on_sigterm(signum: int, _frame: Any) -> None:
    raise SystemExit(128 + signum)


def start_stack(settings: Settings, *, host: str = "127.0.0.1", port: int = 0,
                worker_queues: Sequence[str] = ("cpu", "gpu"), worker_concurrency: int = 1,
                start_worker: bool = True, start_api: bool = True,
                extra_env: dict[str, str] | None = None) -> RunningStack:
    """Start the API (uvicorn, a subprocess) and an embedded or distributed Celery worker (a subprocess).

    Args:
        settings: the whole configuration; passed to both processes through the environment.
        host, port: where the API listens (port 0: a free port).
        worker_queues: queues the worker consumes ("cpu", "gpu").
        worker_concurrency: worker processes.
        start_worker: False for an API alone (e.g. workers on other machines).
        start_api: False for a worker alone (benchmarks).
        extra_env: more environment for both processes.
    Returns:
        The running stack (`.base_url`, `.settings`, `.stop()`); use it as a context manager.
    """

    if unknown := set(worker_queues) - set(QUEUES):
        raise ValueError(f"unknown worker queues {sorted(unknown)}; use {list(QUEUES)}")
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    ensure_embedded_folders(settings)
    env = {k: v for k, v in os.environ.items() if not k.startswith("HANDLOOP_")}
    env.update(settings_env(settings))
    env.update(extra_env or {})
    repo = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = repo + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    stack = RunningStack(settings, host, port or free_port(host), worker_queues, worker_concurrency, env)
    stack.trap_sigterm()
    try:
        if start_api:
            stack.start_api()
        if start_worker:
            stack.start_worker()
    except BaseException:
        stack.stop()
        raise
    return stack
