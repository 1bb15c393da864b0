from __future__ import annotations

import stat
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest
from pydantic import ValidationError

from backend.services.accounts.security import create_token
from backend.services.jobs.jobs import InMemoryJobQueue
from backend.settings import PUBLISHED_SECRET_KEYS, SECRET_KEY_FILE, Settings


def test_api_import_leaves_torch_out():
    code = ("import sys, backend.app, backend.api.main, workers.tasks.records, backend.services.captures.importer; "
            "from backend.app import create_app; create_app(); "
            "assert 'torch' not in sys.modules, 'torch imported'; print('ok')")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                            env={"HANDLOOP_DATABASE_URL": "sqlite://", "PATH": "/usr/bin:/bin"})
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "ok"


@pytest.mark.parametrize("environment", ["development", "test", "production"])
def test_a_published_secret_is_refused_in_every_environment(environment):
    for key in PUBLISHED_SECRET_KEYS:
        with pytest.raises(ValidationError, match="published default"):
            Settings(environment=environment, secret_key=key)


def test_without_a_key_the_data_folder_gets_its_own_random_one(tmp_path):
    key = Settings(data_dir=tmp_path).signing_key
    path = tmp_path / SECRET_KEY_FILE
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert len(key) >= 32 and key not in PUBLISHED_SECRET_KEYS
    assert Settings(data_dir=tmp_path, environment="production").signing_key == key  # a restart reuses it
    assert Settings(data_dir=tmp_path / "other").signing_key != key
    assert Settings(data_dir=tmp_path, secret_key="x" * 32).signing_key == "x" * 32  # a configured key wins


def _signing_key_of(data_dir: str) -> str:
    return Settings(data_dir=Path(data_dir)).signing_key


def test_processes_starting_together_share_one_key(tmp_path):
    """The demo's API and worker start at the same time on one data folder."""
    with ProcessPoolExecutor(4) as pool:
        keys = set(pool.map(_signing_key_of, [str(tmp_path)] * 8))
    assert len(keys) == 1 and (tmp_path / SECRET_KEY_FILE).read_text().strip() in keys
    assert sorted(p.name for p in tmp_path.iterdir()) == [SECRET_KEY_FILE]  # no candidate left behind


def test_a_short_key_file_is_an_error_naming_it(tmp_path):
    (tmp_path / SECRET_KEY_FILE).write_text("short\n")
    with pytest.raises(ValueError, match="secret_key holds no usable secret key"):
        _signing_key_of(str(tmp_path))


def test_a_token_signed_with_the_old_default_is_rejected(sqlite_url, tmp_path):
    """The audit's forgery: an admin token signed with the published default key, on a server started
    without HANDLOOP_SECRET_KEY."""
    from fastapi.testclient import TestClient

    from backend.app import create_app

    app = create_app(Settings(database_url=sqlite_url, data_dir=tmp_path), job_queue=InMemoryJobQueue())
    with TestClient(app) as client:
        for key in PUBLISHED_SECRET_KEYS:
            forged = create_token(key, 3, 0, 3600)  # user 3 is the seeded admin
            response = client.get("/api/admin/users", headers={"Authorization": f"Bearer {forged}"})
            assert response.status_code == 401 and "invalid access token" in response.json()["detail"]
        real = create_token(app.state.settings.signing_key, 3, 0, 3600)
        assert client.get("/api/admin/users", headers={"Authorization": f"Bearer {real}"}).status_code == 200
    app.state.engine.dispose()


def test_database_url_defaults_to_sqlite_in_data_dir(tmp_path):
    assert Settings(data_dir=tmp_path).resolved_database_url == f"sqlite:///{tmp_path / 'handloop.sqlite3'}"


def test_openapi_docs_and_health(sqlite_env):
    assert sqlite_env.client.get("/docs").status_code == 200
    assert "/api/annotate/next" in sqlite_env.client.get("/openapi.json").json()["paths"]
    assert sqlite_env.client.get("/api/health").json() == {"status": "ok"}
