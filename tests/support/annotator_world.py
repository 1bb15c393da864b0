"""An in-process app on a prepared capture with an annotator signed in, and the worker context that runs its
jobs (the fit service's tests: submit through the API, run the fit job in the test's process)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from fastapi.testclient import TestClient

from backend.app import create_app
from backend.services.jobs.jobs import InMemoryJobQueue
from backend.settings import Settings
from tests.support.live_stack import TEST_SETTINGS, USERS, prepare_database
from workers.tasks.context import WorkerContext, build_context


@contextmanager
def annotator_world(data_dir: Path, capture: Path) -> Iterator[tuple[Settings, TestClient, InMemoryJobQueue,
                                                                       WorkerContext]]:
    settings = Settings(data_dir=data_dir, **TEST_SETTINGS)
    prepare_database(settings, capture)
    queue = InMemoryJobQueue()
    app = create_app(settings, job_queue=queue)
    try:
        with TestClient(app) as client:
            user = USERS["annotator"]
            token = client.post("/api/auth/token", data={"username": user.email, "password": user.password}
                                ).json()["access_token"]
            client.headers["Authorization"] = f"Bearer {token}"
            yield settings, client, queue, build_context(settings, job_queue=queue)
    finally:
        app.state.engine.dispose()
