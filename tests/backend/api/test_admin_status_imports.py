"""The admin page's pre-annotation status (GET /api/admin/preannotation, asked on every admin page load) tells
whether the detector can run from the model files' checksums and the runtime's place on the import path: it
imports neither the detector's pipeline nor torch nor the runtime (that import took ~5 s under load and made
the admin page's first load after a start miss its 1 s target). The answer still names what is missing."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from backend.settings import Settings
from tests.support.live_stack import TEST_SETTINGS, USERS, prepare_database, tiny_capture
from workers.detector import model_files

ROOT = Path(__file__).resolve().parents[3]
# What the status must not load: the detector's pipeline and what it pulls in.
RUNTIME_MODULES = ("workers.detector.pipeline", "workers.detector.palm", "workers.detector.landmark_model",
                   "ai_edge_litert", "torch", "cv2", "scipy")

# In a fresh interpreter: the API app on the prepared database, the admin signed in, the status asked for;
# asks for each path; prints the last answer and which of RUNTIME_MODULES each request loaded.
SCRIPT = """
import json, sys
from fastapi.testclient import TestClient
from backend.app import create_app
from backend.settings import Settings
from backend.services.jobs.jobs import InMemoryJobQueue
args = json.loads(sys.argv[1])
watched = args["watched"]
loaded = lambda: sorted(m for m in watched if m in sys.modules)
app = create_app(Settings(**args["settings"]), job_queue=InMemoryJobQueue())
with TestClient(app) as client:
    token = client.post("/api/auth/token", data={"username": args["email"], "password": args["password"]})
    headers = {"Authorization": "Bearer " + token.json()["access_token"]}
    before, imported = loaded(), {}
    for path in args["paths"]:
        answer = client.get(path, headers=headers)
        assert answer.status_code == 200, (path, answer.text)
        imported[path] = [m for m in loaded() if m not in before and all(m not in v for v in imported.values())]
    print(json.dumps({"body": answer.json(), "before": before, "imported": imported}))
"""


# What the admin page asks for when it opens (frontend/js/admin.js), the pre-annotation status last.
PAGE_LOAD = ("/api/admin/rounds/statistics", "/api/admin/rounds", "/api/admin/dashboard", "/api/admin/jobs?limit=25",
             "/api/admin/reliability?bins=10", "/api/admin/users", "/api/admin/preannotation")


def _ask_status(settings: dict, env_extra: dict[str, str], paths: tuple[str, ...] = PAGE_LOAD) -> dict:
    admin = USERS["admin"]
    args = {"settings": settings, "email": admin.email, "password": admin.password, "watched": RUNTIME_MODULES,
            "paths": paths}
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "PYTHONPATH": str(ROOT), **env_extra}
    result = subprocess.run([sys.executable, "-c", SCRIPT, json.dumps(args)], cwd=ROOT, env=env,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-4000:]
    return json.loads(result.stdout.strip().splitlines()[-1])


@pytest.fixture
def database(tmp_path: Path, capture_cache: Path) -> dict:
    settings = {"data_dir": str(tmp_path / "data"), **TEST_SETTINGS}
    prepare_database(Settings(**settings), tiny_capture(capture_cache, frames=2), queue_for_annotation=False)
    return settings


def test_the_status_route_imports_no_detector_runtime(database: dict) -> None:
    answer = _ask_status(database, {})
    assert answer["before"] == [], answer  # the app itself loads none of them
    assert answer["imported"]["/api/admin/preannotation"] == [], answer["imported"]
    assert not any(answer["imported"].values()), f"the admin page's first load imported {answer['imported']}"
    # The route answers the cheap check (asked here in this process: the files as installed here); where it
    # and the workers' check differ is test_a_runtime_that_cannot_load_passes_the_status_but_not_the_workers.
    assert answer["body"]["available"] is (model_files.detector_status() is None)


def test_missing_files_and_a_missing_runtime_are_named_without_importing_them(database: dict,
                                                                             tmp_path: Path) -> None:
    empty = tmp_path / "no-models"
    empty.mkdir()
    answer = _ask_status(database, {model_files.ENV_DIR: str(empty)}, ("/api/admin/preannotation",))
    assert answer["imported"] == {"/api/admin/preannotation": []}, answer
    assert answer["body"]["available"] is False
    assert "hand_landmark_full.tflite is missing" in answer["body"]["reason"], answer["body"]


def test_the_runtime_is_looked_for_on_the_import_path(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(model_files, "RUNTIME", "handloop_no_such_runtime")
    status = model_files.runtime_status()
    assert status is not None and "ai-edge-litert is not installed" in status, status
    monkeypatch.setattr(model_files, "RUNTIME", "json")  # a package without an `interpreter` module
    status = model_files.runtime_status()
    assert status is not None and "ai_edge_litert.interpreter' is missing" in status, status
    monkeypatch.setattr(model_files, "model_files_status", lambda: None)
    monkeypatch.setattr(model_files, "RUNTIME", "handloop_no_such_runtime")
    assert "ai-edge-litert is not installed" in model_files.detector_status()


def test_a_runtime_that_cannot_load_passes_the_status_but_not_the_workers(monkeypatch: pytest.MonkeyPatch,
                                                                         tmp_path: Path) -> None:
    # Installed (on the import path, with its interpreter module) but its native library does not load.
    runtime = tmp_path / "handloop_broken_runtime"
    runtime.mkdir()
    (runtime / "__init__.py").write_text("")
    (runtime / "interpreter.py").write_text(
        "raise ImportError('libLiteRtRuntime.so: cannot open shared object file')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(model_files, "RUNTIME", "handloop_broken_runtime")
    monkeypatch.setattr(model_files, "model_files_status", lambda: None)  # the files as if present and verified
    from backend.services.rounds import preannotation  # deferred: after the runtime is swapped for the broken one
    from workers.detector import detector_status as workers_status  # deferred: the same
    from workers.nets.configs import CONFIGS  # deferred: the same
    from workers.nets.detections import detector_backed  # deferred: the same

    try:
        # The API's status (the admin page's first load) only looks on the import path: available.
        assert model_files.detector_status() is None
        assert preannotation.quick_detector_problem() is None
        # The workers import it (the pre-annotation job's check, MVNet's detector-backed configuration), and so
        # does a launch: refused, not queued to fail.
        for status in (workers_status(), preannotation.detector_problem()):
            assert status is not None and "cannot open shared object file" in status, status
        config, message = detector_backed(CONFIGS["cpu-small-detector"])
        assert config.mvnet.heatmap_source != "detector"
        assert message is not None and "cannot open shared object file" in message, message
    finally:
        sys.modules.pop("handloop_broken_runtime", None)
