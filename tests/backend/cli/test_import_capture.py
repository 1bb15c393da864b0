"""Import of a real (tiny, synthetic) capture through the admin endpoint and `handloop import`."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from sqlalchemy import text

from backend.models.enums import Role

REPO = Path(__file__).resolve().parents[3]
HANDLOOP = str(Path(sys.executable).parent / "handloop")


@pytest.fixture(scope="module")
def capture_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("capture") / "tiny"
    result = subprocess.run([HANDLOOP, "synth", "--out", str(out), "--sequences", "1",
                             "--frames", "2", "--seed", "3", "--width", "64", "--workers", "1"],
                            cwd=REPO, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    return out


def test_admin_import_creates_rows_and_serves_images(sqlite_env, capture_dir):
    env = sqlite_env
    response = env.client.post("/api/admin/imports", headers=env.headers(Role.admin),
                               json={"path": str(capture_dir), "project": "tiny"})
    assert response.status_code == 201, response.text
    data = response.json()
    assert data["samples"] == 2 and data["cameras"] == data["views"] // 2 >= 1
    task = env.client.post("/api/annotate/next", headers=env.headers(Role.annotator)).json()
    view = task["views"][0]
    assert (view["width"], view["height"]) == (64, 64) or view["width"] == 64
    image = env.client.get(view["image_url"], headers=env.headers(Role.annotator))
    assert image.status_code == 200 and image.headers["content-type"] in ("image/jpeg", "image/png")
    again = env.client.post("/api/admin/imports", headers=env.headers(Role.admin),
                            json={"path": str(capture_dir), "project": "tiny"})
    assert again.status_code == 409 and "already exists" in again.json()["detail"]


def test_broken_capture_is_refused_and_writes_nothing(sqlite_env, capture_dir, tmp_path):
    env = sqlite_env
    broken = tmp_path / "broken"
    subprocess.run(["cp", "-r", str(capture_dir), str(broken)], check=True)
    (broken / "calibration.json").write_text("{not json")
    response = env.client.post("/api/admin/imports", headers=env.headers(Role.admin), json={"path": str(broken)})
    assert response.status_code == 422
    assert "capture rejected" in response.json()["detail"] and "calibration.json" in response.json()["detail"]
    with env.session() as s:
        assert s.execute(text("SELECT count(*) FROM projects")).scalar_one() == 0


# Files cut short that pass the structure and header checks (each imported with 201 before full verification).
BROKEN_FILES = {
    "jpeg-cut-at-1100-bytes": ("sequences/seq000/images/cam0/000001.jpg", lambda size: 1100),
    "truncated-mask-png": ("sequences/seq000/masks/cam0/000000.png", lambda size: size // 2),
    "truncated-ground-truth-npz": ("sequences/seq000/ground_truth/000001.npz", lambda size: size // 2),
}


def _break(capture_dir: Path, tmp_path: Path, case: str) -> tuple[Path, Path]:
    broken = tmp_path / "broken"
    subprocess.run(["cp", "-r", str(capture_dir), str(broken)], check=True)
    relative, keep = BROKEN_FILES[case]
    path = broken / relative
    data = path.read_bytes()
    assert len(data) > keep(len(data)), "the file is already shorter than the cut"
    path.write_bytes(data[:keep(len(data))])
    return broken, path


def _stored_files(data_dir: Path) -> list[Path]:
    return [p for p in (data_dir / "storage").rglob("*") if p.is_file()] if (data_dir / "storage").exists() else []


@pytest.mark.parametrize("case", sorted(BROKEN_FILES))
def test_admin_import_of_a_truncated_file_is_refused_naming_it_and_writes_nothing(sqlite_env, capture_dir, tmp_path,
                                                                                    case):
    env = sqlite_env
    broken, path = _break(capture_dir, tmp_path, case)
    response = env.client.post("/api/admin/imports", headers=env.headers(Role.admin), json={"path": str(broken)})
    assert response.status_code == 422, response.text
    assert str(path) in response.json()["detail"] and "nothing was imported" in response.json()["detail"]
    with env.session() as s:
        for table in ("projects", "samples", "views", "masks"):
            assert s.execute(text(f"SELECT count(*) FROM {table}")).scalar_one() == 0, table
    assert _stored_files(env.settings.data_dir) == []


@pytest.mark.parametrize("case", sorted(BROKEN_FILES))
def test_cli_import_of_a_truncated_file_is_refused_naming_it_and_writes_nothing(capture_dir, tmp_path, case):
    data_dir = tmp_path / "data"
    env = {**os.environ, "HANDLOOP_DATA_DIR": str(data_dir)}
    env.pop("HANDLOOP_DATABASE_URL", None)
    assert subprocess.run([HANDLOOP, "db", "upgrade"], cwd=REPO, env=env, capture_output=True, timeout=300
                          ).returncode == 0
    broken, path = _break(capture_dir, tmp_path, case)
    refused = subprocess.run([HANDLOOP, "import", str(broken)], cwd=REPO, env=env, capture_output=True, text=True,
                             timeout=300)
    assert refused.returncode == 2 and str(path) in refused.stderr, refused.stderr[-2000:]
    assert _stored_files(data_dir) == []
    import sqlite3

    with sqlite3.connect(data_dir / "handloop.sqlite3") as db:
        assert db.execute("SELECT count(*) FROM projects").fetchone()[0] == 0


def test_cli_import_and_users(capture_dir, tmp_path):
    env = {**os.environ, "HANDLOOP_DATA_DIR": str(tmp_path), "HANDLOOP_NEW_USER_PASSWORD": "password-123"}
    env.pop("HANDLOOP_DATABASE_URL", None)

    def cli(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([HANDLOOP, *args], cwd=REPO, env=env,
                              capture_output=True, text=True, timeout=300)

    assert cli("db", "upgrade").returncode == 0
    from alembic.script import ScriptDirectory

    from backend.db.migrate import alembic_config

    head = ScriptDirectory.from_config(alembic_config("sqlite://")).get_current_head()
    assert cli("db", "current").stdout.strip() == head
    imported = cli("import", str(capture_dir))
    assert imported.returncode == 0, imported.stderr[-2000:]
    assert json.loads(imported.stdout.strip().splitlines()[-1])["samples"] == 2
    created = cli("users", "create", "boss@example.org", "--role", "admin")
    assert created.returncode == 0 and "admin" in created.stdout
    assert "boss@example.org" in cli("users", "list").stdout
    refused = cli("import", str(tmp_path / "nowhere"))
    assert refused.returncode == 2 and "capture folder not found" in refused.stderr
    assert cli("db", "downgrade", "base").returncode == 0


def _variant(capture_dir: Path, out: Path, **header: object) -> Path:
    """A copy of the capture with capture.json's fields changed (`hand_model_side` sets hand_model.side)."""
    subprocess.run(["cp", "-r", str(capture_dir), str(out)], check=True)
    data = json.loads((out / "capture.json").read_text())
    side = header.pop("hand_model_side", None)
    if side is not None:
        data["hand_model"]["side"] = side
    data.update(header)
    (out / "capture.json").write_text(json.dumps(data))
    return out


def test_the_captures_hand_side_is_stored_per_sequence_and_named_on_the_task(sqlite_env, capture_dir, tmp_path):
    env = sqlite_env
    # A right-hand capture whose one sequence says it is a left hand (sequence.json 'hand_side', version 2).
    mixed = _variant(capture_dir, tmp_path / "mixed", version=2)
    sequence_json = next((mixed / "sequences").iterdir()) / "sequence.json"
    sequence_json.write_text(json.dumps({**json.loads(sequence_json.read_text()), "hand_side": "left"}))
    for name, path in (("right-hands", capture_dir), ("left-hands", _variant(capture_dir, tmp_path / "left",
                                                                             hand_model_side="left")),
                       ("mixed", mixed)):
        response = env.client.post("/api/admin/imports", headers=env.headers(Role.admin),
                                   json={"path": str(path), "project": name})
        assert response.status_code == 201, response.text
    with env.session() as s:
        sides = dict(s.execute(text("SELECT p.name, q.side FROM sequences q JOIN projects p ON p.id = q.project_id"))
                     .all())
    assert sides == {"right-hands": "right", "left-hands": "left", "mixed": "left"}
    task = env.client.post("/api/annotate/next", headers=env.headers(Role.annotator)).json()
    assert task["side"] == "right"  # the right hands' project came first
    with env.session() as s, s.begin():  # only the left hands' samples left in the queue
        s.execute(text("UPDATE samples SET state = 'unlabeled', leased_by_id = NULL, lease_kind = NULL, "
                       "lease_token = NULL, lease_expires_at = NULL WHERE sequence_id IN "
                       "(SELECT q.id FROM sequences q JOIN projects p ON p.id = q.project_id "
                       "WHERE p.name <> 'left-hands')"))
    task = env.client.post("/api/annotate/next", headers=env.headers(Role.annotator)).json()
    assert task["side"] == "left", task


def test_a_working_width_narrower_than_the_images_serves_a_derived_copy_and_keeps_the_original(
        sqlite_env, capture_dir, tmp_path):
    import cv2
    import numpy as np

    env = sqlite_env
    path = _variant(capture_dir, tmp_path / "wide", version=2, working_width_px=32)
    response = env.client.post("/api/admin/imports", headers=env.headers(Role.admin),
                               json={"path": str(path), "project": "wide"})
    assert response.status_code == 201, response.text
    task = env.client.post("/api/annotate/next", headers=env.headers(Role.annotator)).json()
    view = task["views"][0]
    assert view["width"] == 64  # the view (and its clicks) stay in full-resolution pixels

    def decoded(url: str) -> np.ndarray:
        answer = env.client.get(url, headers=env.headers(Role.annotator))
        assert answer.status_code == 200, answer.text
        return cv2.imdecode(np.frombuffer(answer.content, np.uint8), cv2.IMREAD_COLOR)

    working, original = decoded(view["image_url"]), decoded(view["image_url"] + "?full=true")
    assert working.shape[1] == 32 and original.shape[1] == 64
    assert working.shape[0] == round(original.shape[0] * 32 / 64)
    # The copy is the original averaged down, not another image.
    expected = cv2.resize(original, (32, working.shape[0]), interpolation=cv2.INTER_AREA).astype(float)
    assert np.abs(working.astype(float) - expected).mean() < 4.0
    assert decoded(view["image_url"]).shape == working.shape  # derived once, then served from storage
