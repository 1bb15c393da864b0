"""A live handloop for integration tests: real API process, real Celery worker process, real database.

    def test_something(live_stack):
        stack = live_stack()                       # embedded broker, SQLite, a tiny synthetic capture
        with stack.client("annotator") as http:
            task = http.post("/api/annotate/next").json()

`live_stack(**options)` (a fixture factory; every stack is stopped after the test) synthesises (or reuses,
per test session and parameters) a tiny capture, migrates a fresh database in a temporary data folder,
imports the capture, creates one user per role with known passwords (`USERS`), and starts
`backend.runtime.start_stack`. Options:
    frames, sequences, width: the capture (default 3 frames x 1 sequence, 160 px);
    broker: "embedded" (default) or "redis" (HANDLOOP_TEST_REDIS_URL, default redis://127.0.0.1:6379/0,
        under a key prefix of its own); or broker_url= any URL;
    database: "sqlite" (default, a file in the data folder) or "postgres" (a fresh database on the server
        at HANDLOOP_TEST_PG_URL, dropped afterwards); or database_url= any URL;
    queue_for_annotation: import samples as 'needs_annotation' (default) or 'unlabeled';
    worker: start the worker (default True);
    **settings: any other Settings field (e.g. fit_full_iterations=20).
Redis absent: the test is skipped, or fails when CI is set.
"""

from __future__ import annotations

import os
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest

from backend.runtime import RunningStack, start_stack
from backend.settings import Settings
from tests.support.requirements import missing

SECRET = "live-stack-secret-key-0123456789"
REDIS_URL = os.environ.get("HANDLOOP_TEST_REDIS_URL", "redis://127.0.0.1:6379/0")
PG_ADMIN_URL = os.environ.get("HANDLOOP_TEST_PG_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/postgres")


@dataclass(frozen=True)
class Credentials:
    email: str
    password: str
    role: str


USERS: dict[str, Credentials] = {
    role: Credentials(f"{role}@stack.test", f"{role}-password-123", role) for role in ("admin", "reviewer", "annotator")
}

# Small but real: the `tiny` networks, short fits and training budgets, quick outbox and heartbeats.
TEST_SETTINGS: dict[str, Any] = {
    "environment": "test", "secret_key": SECRET, "nets_config": "tiny", "round_handsegnet_budget_s": 4.0,
    "round_mvnet_budget_s": 6.0, "fit_global_iterations": 15, "fit_full_iterations": 25, "outbox_poll_s": 0.5,
    "predict_batch_size": 4, "fit_batch_size": 4, "round_min_training_samples": 1,
    # The tests' captures live under the temporary folder: the admin page imports them from there.
    "import_roots": [tempfile.gettempdir()],
}


@dataclass
class LiveStack:
    """A running stack and what a test needs to drive it."""

    base_url: str
    settings: Settings
    data_dir: Path
    capture_dir: Path
    project_id: int
    users: dict[str, Credentials]
    stack: RunningStack
    _tokens: dict[str, str] = field(default_factory=dict)

    def token(self, role: str) -> str:
        if role not in self._tokens:
            user = self.users[role]
            response = httpx.post(self.base_url + "/api/auth/token",
                                  data={"username": user.email, "password": user.password}, timeout=30)
            response.raise_for_status()
            self._tokens[role] = response.json()["access_token"]
        return self._tokens[role]

    def client(self, role: str | None = None, timeout_s: float = 30.0) -> httpx.Client:
        headers = {"Authorization": f"Bearer {self.token(role)}"} if role else {}
        return httpx.Client(base_url=self.base_url, headers=headers, timeout=timeout_s)

    def session_factory(self) -> Any:
        from backend.db.session import create_engine_from_url, make_session_factory

        return make_session_factory(create_engine_from_url(self.settings.resolved_database_url))

    def wait_for_job(self, job_id: int, timeout_s: float = 300.0, poll_s: float = 0.5) -> dict[str, Any]:
        """Poll GET /api/admin/jobs/{id} until the job is final; its last state."""
        deadline = time.monotonic() + timeout_s
        with self.client("admin") as http:
            while True:
                job = http.get(f"/api/admin/jobs/{job_id}").json()
                if job["state"] in ("succeeded", "failed", "cancelled"):
                    return job
                if time.monotonic() > deadline:
                    raise TimeoutError(f"job {job_id} still {job['state']} after {timeout_s} s: {job}\n"
                                       f"worker log:\n{self.stack.worker_log.read_text()[-4000:]}")
                time.sleep(poll_s)

    def stop(self) -> None:
        self.stack.stop()


def tiny_capture(root: Path, *, frames: int = 3, sequences: int = 1, width: int = 160, seed: int = 0,
                 side: str = "right") -> Path:
    """A synthetic capture of a `side` hand under `root` (reused when it is already there and valid)."""
    from workers.capture import CaptureError, read_capture
    from workers.synth.generator import generate_capture
    from workers.synth.plan import SynthConfig

    out = root / (f"capture-s{sequences}-f{frames}-w{width}-seed{seed}" + ("-left" if side == "left" else ""))
    if out.exists():
        try:
            read_capture(out, check_images=False)
            return out
        except CaptureError:
            pass
    generate_capture(out, SynthConfig(num_sequences=sequences, frames_per_sequence=frames, seed=seed, width_px=width,
                                      side=side), workers=1, force=True)
    return out


def redis_available(url: str = REDIS_URL) -> str | None:
    """None when Redis answers at `url`, else why not."""
    import redis

    try:
        redis.Redis.from_url(url, socket_connect_timeout=2).ping()
        return None
    except Exception as exc:
        return f"{exc.__class__.__name__}: {exc}"


def require_redis(url: str = REDIS_URL) -> str:
    problem = redis_available(url)
    if problem:
        message = f"Redis is unreachable at {url}: {problem}"
        missing(message, needed_by="the Redis tests")
    return url


@contextmanager
def fresh_postgres() -> Iterator[str]:
    """A new, empty PostgreSQL database (dropped afterwards); skipped, or failed in CI, without a server."""
    from sqlalchemy import create_engine, text

    admin = create_engine(PG_ADMIN_URL, isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as conn:
            conn.execute(text("SELECT 1"))
    except Exception as exc:
        admin.dispose()
        message = f"PostgreSQL is unreachable at {PG_ADMIN_URL}: {exc.__class__.__name__}"
        missing(message, needed_by="the PostgreSQL tests")
    name = f"handloop_live_{uuid.uuid4().hex[:10]}"
    with admin.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}"'))
    try:
        yield PG_ADMIN_URL.rsplit("/", 1)[0] + f"/{name}"
    finally:
        with admin.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


def prepare_database(settings: Settings, capture_dir: Path, *, queue_for_annotation: bool = True) -> int:
    """Migrate, import the capture, create USERS; returns the project id."""
    from backend.db.migrate import upgrade
    from backend.db.session import create_engine_from_url, make_session_factory
    from backend.models.enums import Role
    from backend.models.label_audit import QualitySettings
    from backend.services.accounts.users import create_user
    from backend.services.captures.importer import import_capture
    from backend.services.captures.storage import LocalDiskStorage

    settings.data_dir.mkdir(parents=True, exist_ok=True)
    upgrade(settings.resolved_database_url)
    engine = create_engine_from_url(settings.resolved_database_url)
    try:
        with make_session_factory(engine).begin() as session:
            result = import_capture(session, LocalDiskStorage(settings.storage_dir), capture_dir, project_name="live",
                                    queue_for_annotation=queue_for_annotation)
            for user in USERS.values():
                create_user(session, user.email, user.password, Role(user.role), user.role)
            # Blind audits off (the product audits 5 % of accepts): a test opts in (test_review_audit_blind.py).
            session.add(QualitySettings(id=1, audit_share=0.0, agreement_share=0.0))
    finally:
        engine.dispose()
    return result.project_id


def make_live_stack(data_dir: Path, capture_dir: Path, *, broker: str = "embedded", broker_url: str | None = None,
                    database_url: str | None = None, queue_for_annotation: bool = True, worker: bool = True,
                    worker_concurrency: int = 1, **overrides: Any) -> LiveStack:
    if broker == "redis" and broker_url is None:
        broker_url = require_redis()
        overrides.setdefault("broker_prefix", f"handloop-test-{uuid.uuid4().hex[:10]}:")
    settings = Settings(data_dir=data_dir, database_url=database_url, broker_url=broker_url,
                        **{**TEST_SETTINGS, **overrides})
    project_id = prepare_database(settings, capture_dir, queue_for_annotation=queue_for_annotation)
    _share_hand_model_cache(data_dir)
    stack = start_stack(settings, worker_concurrency=worker_concurrency, start_worker=worker)
    return LiveStack(stack.base_url, settings, data_dir, capture_dir, project_id, dict(USERS), stack)


def _share_hand_model_cache(data_dir: Path) -> None:
    """Copy this process's generated built-in hand into the stack's cache (the worker would regenerate it)."""
    import shutil

    from workers.handmodel.builtin import cache

    target = data_dir / "cache"
    target.mkdir(parents=True, exist_ok=True)
    for path in cache.cache_dir().glob("builtin_hand_*.npz"):
        if not (target / path.name).exists():
            shutil.copyfile(path, target / path.name)


@pytest.fixture(scope="session")
def capture_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cache = os.environ.get("HANDLOOP_TEST_CAPTURE_CACHE")
    if cache:
        Path(cache).mkdir(parents=True, exist_ok=True)
        return Path(cache)
    return tmp_path_factory.mktemp("captures")


@pytest.fixture
def live_stack(tmp_path: Path, capture_cache: Path) -> Iterator[Callable[..., LiveStack]]:
    """Factory: live_stack(**options) -> LiveStack (see the module docstring); stopped after the test."""
    stacks: list[LiveStack] = []

    databases = ExitStack()

    def make(*, frames: int = 3, sequences: int = 1, width: int = 160, seed: int = 0, database: str = "sqlite",
             side: str = "right", **options: Any) -> LiveStack:
        capture = tiny_capture(capture_cache, frames=frames, sequences=sequences, width=width, seed=seed, side=side)
        data_dir = tmp_path / f"stack-{len(stacks)}"
        if database == "postgres" and "database_url" not in options:
            options["database_url"] = databases.enter_context(fresh_postgres())
        stack = make_live_stack(data_dir, capture, **options)
        stacks.append(stack)
        return stack

    with databases:
        yield make
        for stack in stacks:
            stack.stop()
