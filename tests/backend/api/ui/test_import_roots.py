"""Issue 38 item 12: `POST /api/admin/imports` takes captures only from the configured import roots (a relative
path is not read against the server's working folder) and follows no symbolic link out of the capture."""

from __future__ import annotations

import shutil

from backend.models.enums import Role


def _import(env, path) -> object:
    return env.client.post("/api/admin/imports", headers=env.headers(Role.admin),
                           json={"path": str(path), "project": "roots"})


def test_imports_come_from_the_import_roots_only(env_with, db_url, tmp_path, ui_capture, h):
    roots = tmp_path / "roots"
    roots.mkdir()
    env = env_with(db_url, tmp_path / "data", import_roots=[roots])
    outside = _import(env, ui_capture)  # a folder the server can read, but not under a root
    assert outside.status_code == 422 and "outside the import roots" in outside.json()["detail"]
    assert str(roots) in outside.json()["detail"]
    relative = _import(env, "roots/tiny")
    assert relative.status_code == 422 and "relative" in relative.json()["detail"]
    (roots / "alias").symlink_to(ui_capture, target_is_directory=True)  # inside by name, outside by link
    alias = _import(env, roots / "alias")
    assert alias.status_code == 422 and "outside the import roots" in alias.json()["detail"]
    # A sequence folder linked to outside the capture: refused, nothing written.
    linked = roots / "linked"
    shutil.copytree(ui_capture, linked, symlinks=True)
    sequence = next(p for p in (linked / "sequences").iterdir() if p.is_dir())
    shutil.rmtree(sequence)
    sequence.symlink_to(ui_capture / "sequences" / sequence.name, target_is_directory=True)
    escaped = _import(env, linked)
    assert escaped.status_code == 422 and "leads outside the capture folder" in escaped.json()["detail"]
    assert h.count(env, "projects") == 0
    shutil.copytree(ui_capture, roots / "tiny")
    assert _import(env, roots / "tiny").status_code == 201
    assert h.count(env, "projects") == 1


def test_without_import_roots_the_data_folders_captures_is_the_root(env_with, db_url, tmp_path, ui_capture):
    env = env_with(db_url, tmp_path / "data", import_roots=[])
    assert env.settings.allowed_import_roots == [(tmp_path / "data" / "captures").resolve()]
    refused = _import(env, ui_capture)
    assert refused.status_code == 422 and "HANDLOOP_IMPORT_ROOTS" in refused.json()["detail"]
    shutil.copytree(ui_capture, tmp_path / "data" / "captures" / "tiny")
    assert _import(env, tmp_path / "data" / "captures" / "tiny").status_code == 201
