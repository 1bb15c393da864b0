"""Fixtures for the backend: a migrated database per test on SQLite and on PostgreSQL, an app with an
in-memory job queue, and one user per role with ready-made tokens.

PostgreSQL: a template database is migrated once per run and each test gets a fresh copy
(`handloop_test_<random>`), dropped afterwards. Without a reachable server the PostgreSQL tests are
skipped, or fail when the CI environment variable is set.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text
from sqlalchemy.orm import Session

from backend.app import create_app
from backend.db.migrate import upgrade
from backend.db.session import create_engine_from_url, make_session_factory
from backend.models.enums import Role
from backend.services.accounts.security import create_token, hash_password
from backend.services.jobs.jobs import InMemoryJobQueue
from backend.settings import Settings
from tests.support.requirements import missing

PG_ADMIN_URL = os.environ.get("HANDLOOP_TEST_PG_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/postgres")
SECRET = "test-secret-key-0123456789"
PASSWORD = "correct horse battery"
USERS = {Role.annotator: "ann@example.org", Role.reviewer: "rev@example.org", Role.admin: "admin@example.org"}


def _seed_users(url: str) -> None:
    engine = create_engine_from_url(url)
    hashed = hash_password(PASSWORD)  # once: Argon2 is slow on purpose
    with engine.begin() as conn:
        for role, email in USERS.items():
            conn.execute(text("INSERT INTO users (email, full_name, role, hashed_password, is_active, token_version,"
                              " created_at) VALUES (:e, '', :r, :h, true, 0, CURRENT_TIMESTAMP)"),
                         {"e": email, "r": role.value, "h": hashed})
        # Blind audits off (the product audits 5 % of accepts): a test opts in (tests/backend/api/test_label_audits.py).
        conn.execute(text("INSERT INTO quality_settings (id, audit_share, audit_seed, min_audits_for_target, "
                          "auditor_error_rate, gold_share, updated_at) VALUES (1, 0, 0, 30, 0, 0, CURRENT_TIMESTAMP)"))
    engine.dispose()


@pytest.fixture(scope="session")
def sqlite_template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("sqlite-template") / "template.sqlite3"
    upgrade(f"sqlite:///{path}")
    _seed_users(f"sqlite:///{path}")
    return path


def _pg_admin_engine():
    return create_engine(PG_ADMIN_URL, isolation_level="AUTOCOMMIT")


@pytest.fixture(scope="session")
def pg_template() -> Iterator[str]:
    engine = _pg_admin_engine()
    try:
        with engine.connect() as conn:
            conn.execute(text("SELECT 1"))
    except Exception as exc:
        engine.dispose()
        message = f"PostgreSQL is unreachable at {PG_ADMIN_URL}: {exc.__class__.__name__}: {exc}"
        missing(message, needed_by="the PostgreSQL tests")
    name = f"handloop_tmpl_{uuid.uuid4().hex[:10]}"
    with engine.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}"'))
    url = PG_ADMIN_URL.rsplit("/", 1)[0] + f"/{name}"
    try:
        upgrade(url)
        _seed_users(url)
        yield name
    finally:
        with engine.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        engine.dispose()


@pytest.fixture
def sqlite_url(sqlite_template: Path, tmp_path: Path) -> str:
    path = tmp_path / "handloop.sqlite3"
    shutil.copyfile(sqlite_template, path)
    return f"sqlite:///{path}"


@pytest.fixture
def pg_url(pg_template: str) -> Iterator[str]:
    engine = _pg_admin_engine()
    name = f"handloop_test_{uuid.uuid4().hex[:10]}"
    with engine.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}" TEMPLATE "{pg_template}"'))
    try:
        yield PG_ADMIN_URL.rsplit("/", 1)[0] + f"/{name}"
    finally:
        with engine.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        engine.dispose()


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def db_url(request: pytest.FixtureRequest) -> str:
    """Both backends: tests using this run twice."""
    return request.getfixturevalue("sqlite_url" if request.param == "sqlite" else "pg_url")


@dataclass
class Env:
    """A running app (in-process) and its collaborators."""

    client: TestClient
    settings: Settings
    queue: InMemoryJobQueue
    session_factory: object
    user_ids: dict[Role, int]

    def headers(self, role: Role) -> dict[str, str]:
        token = create_token(self.settings.secret_key, self.user_ids[role], 0, 3600)
        return {"Authorization": f"Bearer {token}"}

    def session(self) -> Session:
        return self.session_factory()  # type: ignore[operator]

    def app_cache(self):
        """The app's token -> user cache (backend.services.accounts.auth_cache.AuthCache)."""
        return self.client.app.state.auth_cache


def make_settings(url: str, data_dir: Path, **overrides: object) -> Settings:
    # The tests' captures are written under pytest's temporary folders: the API imports from there.
    overrides.setdefault("import_roots", [Path(tempfile.gettempdir())])
    return Settings(database_url=url, data_dir=data_dir, secret_key=SECRET, environment="test", **overrides)


def _env(url: str, data_dir: Path, **overrides: object) -> Iterator[Env]:
    settings = make_settings(url, data_dir, **overrides)
    queue = InMemoryJobQueue()
    app = create_app(settings, job_queue=queue)
    with app.state.session_factory() as session:
        ids = dict(session.execute(text("SELECT role, id FROM users")).all())
    with TestClient(app) as client:
        yield Env(client, settings, queue, app.state.session_factory, {Role(k): v for k, v in ids.items()})
    app.state.engine.dispose()


@pytest.fixture
def env(db_url: str, tmp_path: Path) -> Iterator[Env]:
    """App on both backends."""
    yield from _env(db_url, tmp_path)


@pytest.fixture
def sqlite_env(sqlite_url: str, tmp_path: Path) -> Iterator[Env]:
    """App on SQLite only (for wide, backend-independent tests such as the role matrix)."""
    yield from _env(sqlite_url, tmp_path)


@pytest.fixture
def env_with() -> Iterator:
    """env_with(url, data_dir, **settings overrides) -> Env, closed after the test."""
    generators = []

    def make(url: str, data_dir: Path, **overrides: object) -> Env:
        gen = _env(url, data_dir, **overrides)
        generators.append(gen)
        return next(gen)

    yield make
    for gen in generators:
        gen.close()


@pytest.fixture
def engine_factory():
    engines = []

    def make(url: str):
        engine = create_engine_from_url(url)
        engines.append(engine)
        return make_session_factory(engine)

    yield make
    for engine in engines:
        engine.dispose()


# --- helpers shared by the test modules (as fixtures, since tests/ is not a package) -------------------


class Helpers:
    @staticmethod
    def seed(env: Env, **kwargs: object) -> list[int]:
        from backend.services.captures.seed import seed_samples

        with env.session() as session, session.begin():
            return seed_samples(session, **kwargs)  # type: ignore[arg-type]

    @staticmethod
    def body(task: dict, client_id: str | None = None, **overrides: object) -> dict:
        """A valid submission for a task: every sparse keypoint in every view, inside the image."""
        clicks = [{"view_id": v["id"], "keypoint": k, "x": 10.0 + k, "y": 20.0, "visibility": "visible"}
                  for v in task["views"] for k in task["keypoints_to_click"]]
        body = {"submission_id": client_id or uuid.uuid4().hex, "lease_token": task["lease_token"],
                "time_spent_s": 12.5, "clicks": clicks}
        body.update(overrides)
        return body

    @staticmethod
    def next_task(env: Env, role: Role = Role.annotator, queue: str = "annotate") -> dict:
        response = env.client.post(f"/api/{queue}/next", headers=env.headers(role))
        assert response.status_code == 200, response.text
        return response.json()

    @staticmethod
    def record_fit(env: Env, sample_id: int, *, prediction: dict | None = None, ious: float = 0.9,
                   articulation: float = 1.0, offset_m: float = 0.0, from_clicks: bool = False,
                   detection: dict | None = None, fit_keypoints_m: list | None = None) -> int:
        """Record (as a worker would) a fit for a sample in 'fitting'; returns the fit id. `detection`: a
        pre-annotation's fit from this detection record (points_world, confidence), judged by the detector's
        heuristic at its default thresholds (as is a later fit from a prediction against it, and it against the
        prediction, when the settings' `cross_heuristic` and `earlier_fit_check` are on)."""
        import numpy as np

        from backend.services.captures.samples import views_of
        from backend.services.review.verification import HeuristicThresholds
        from workers.tasks import cross_checks, records

        with env.session() as session, session.begin():
            prediction_id = None
            keypoints = np.linspace(0, 0.1, 63).reshape(21, 3)
            if prediction is not None:
                prediction_id = records.record_prediction(
                    session, env.client.app.state.storage, sample_id, keypoints_m=keypoints.tolist(),
                    mvnet_version="mvnet-test", **prediction).id
            views = views_of(session, sample_id, with_masks=False)
            params = [0.0] * 61
            params[10] = articulation
            fit = records.record_fit(
                session, sample_id, params=params,
                keypoints_m=fit_keypoints_m if fit_keypoints_m is not None else (keypoints + offset_m).tolist(),
                view_ious={v.id: ious for v in views}, diagnostics={"loss": 0.1},
                inputs=({"submission_ids": [1]} if from_clicks else {"source": "detector", "detection": detection}
                        if detection is not None else {"prediction_id": prediction_id}),
                model_file="builtin", thresholds=HeuristicThresholds(), prediction_id=prediction_id,
                detector_thresholds=HeuristicThresholds.from_settings(env.settings, "detector_heuristic_"),
                cross_thresholds=cross_checks.thresholds_from_settings(env.settings)[0],
                earlier_fit_thresholds=cross_checks.thresholds_from_settings(env.settings)[1],
                review_pre_annotation_fit=env.settings.review_pre_annotation_fit)
            return fit.id

    @staticmethod
    def set_state(env: Env, sample_ids: list[int], state: str) -> None:
        with env.session() as session, session.begin():
            session.execute(text("UPDATE samples SET state = :s WHERE id IN (" + ",".join(map(str, sample_ids))
                                 + ")"), {"s": state})

    @staticmethod
    def count(env: Env, table: str) -> int:
        with env.session() as session:
            return session.execute(text(f"SELECT count(*) FROM {table}")).scalar_one()


@pytest.fixture
def h() -> type[Helpers]:
    return Helpers
