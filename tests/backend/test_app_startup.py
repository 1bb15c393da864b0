from __future__ import annotations

import subprocess
import sys

import pytest
from pydantic import ValidationError

from backend.settings import DEFAULT_SECRET_KEY, Settings


def test_api_import_leaves_torch_out():
    code = ("import sys, backend.app, backend.api.main, backend.services.records, backend.services.importer; "
            "from backend.app import create_app; create_app(); "
            "assert 'torch' not in sys.modules, 'torch imported'; print('ok')")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                            env={"HANDLOOP_DATABASE_URL": "sqlite://", "PATH": "/usr/bin:/bin"})
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "ok"


def test_default_secret_refused_outside_development():
    with pytest.raises(ValidationError, match="HANDLOOP_SECRET_KEY must be set"):
        Settings(environment="production")
    assert Settings(environment="development").secret_key == DEFAULT_SECRET_KEY


def test_database_url_defaults_to_sqlite_in_data_dir(tmp_path):
    assert Settings(data_dir=tmp_path).resolved_database_url == f"sqlite:///{tmp_path / 'handloop.sqlite3'}"


def test_openapi_docs_and_health(sqlite_env):
    assert sqlite_env.client.get("/docs").status_code == 200
    assert "/api/annotate/next" in sqlite_env.client.get("/openapi.json").json()["paths"]
    assert sqlite_env.client.get("/api/health").json() == {"status": "ok"}
