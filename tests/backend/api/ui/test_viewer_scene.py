"""The 3D view: viser's client at /viewer/ and one recording per sample behind a scene ticket."""

from __future__ import annotations

import msgspec
import zstandard

from backend.models.enums import Role
from backend.services.display import scene_tickets


def decode_recording(data: bytes) -> dict:
    """A `.viser` file: 8-byte inner size, then zstd of (8-byte msgpack length, msgpack, binary buffers)."""
    inner_size = int.from_bytes(data[:8], "little")
    inner = zstandard.ZstdDecompressor().decompress(data[8:], max_output_size=inner_size)
    length = int.from_bytes(inner[:8], "little")
    return msgspec.msgpack.decode(inner[8:8 + length])


def _scene(env, ui, ui_capture):
    task = ui.in_review(env, ui_capture)
    overlay = env.client.get(f"/api/review/samples/{task['sample_id']}/overlay", headers=env.headers(Role.reviewer))
    return task, overlay.json()


def test_recording_holds_mesh_skeleton_label_and_one_frustum_per_view(sqlite_env, ui, ui_capture):
    env = sqlite_env
    task, overlay = _scene(env, ui, ui_capture)
    response = env.client.get(overlay["scene_path"])  # no bearer token: the ticket is the credential
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "application/octet-stream"
    recording = decode_recording(response.content)
    names = {m[1].get("name") for m in recording["messages"]}
    types = [m[1]["type"] for m in recording["messages"]]
    assert {"/fit/mesh", "/fit/skeleton", "/fit/keypoints", "/fit/label"} <= names
    assert sum(t == "CameraFrustumMessage" for t in types) == len(task["views"])
    label = next(m[1] for m in recording["messages"] if m[1].get("name") == "/fit/label")
    assert label["props"]["text"] == "built-in stand-in hand, not MANO"
    again = env.client.get(overlay["scene_path"], headers={"If-None-Match": response.headers["etag"]})
    assert again.status_code == 304


def test_bad_tickets_are_refused(sqlite_env, ui, ui_capture):
    env = sqlite_env
    task, overlay = _scene(env, ui, ui_capture)
    sid = task["sample_id"]
    base = f"/api/viewer/samples/{sid}/scene"
    assert env.client.get(base).status_code == 401
    assert "malformed" in env.client.get(base + "?ticket=abc").json()["detail"]
    ticket = overlay["scene_path"].split("ticket=")[1]
    forged = ticket[:-3] + ("AAA" if not ticket.endswith("AAA") else "BBB")
    assert env.client.get(f"{base}?ticket={forged}").status_code == 401
    other = env.client.get(f"/api/viewer/samples/{sid + 1}/scene?ticket={ticket}")
    assert other.status_code == 403 and f"for sample {sid}" in other.json()["detail"]
    secret = env.settings.secret_key
    expired = scene_tickets.issue(secret, env.user_ids[Role.reviewer], sid, overlay["fit_id"], token_version=0,
                                  lifetime_s=-5)
    response = env.client.get(f"{base}?ticket={expired}")
    assert response.status_code == 401 and "expired" in response.json()["detail"]
    annotator = scene_tickets.issue(secret, env.user_ids[Role.annotator], sid, overlay["fit_id"], token_version=0)
    response = env.client.get(f"{base}?ticket={annotator}")
    assert response.status_code == 403 and "reviewer" in response.json()["detail"]
    wrong_fit = scene_tickets.issue(secret, env.user_ids[Role.reviewer], sid, overlay["fit_id"] + 100,
                                    token_version=0)
    assert env.client.get(f"{base}?ticket={wrong_fit}").status_code == 404


def test_a_password_change_revokes_the_scene_ticket(sqlite_env, ui, ui_capture):
    """Like an access token: the ticket carries the token version, and a password change bumps it."""
    env = sqlite_env
    _task, overlay = _scene(env, ui, ui_capture)
    assert env.client.get(overlay["scene_path"]).status_code == 200
    changed = env.client.patch(f"/api/admin/users/{env.user_ids[Role.reviewer]}", json={"password": "a new password 1"},
                               headers=env.headers(Role.admin))
    assert changed.status_code == 200, changed.text
    response = env.client.get(overlay["scene_path"])
    assert response.status_code == 401 and "revoked" in response.json()["detail"], response.text


def test_viser_client_and_the_ui_are_served(sqlite_env):
    client = sqlite_env.client
    viewer = client.get("/viewer/")
    assert viewer.status_code == 200 and "text/html" in viewer.headers["content-type"] and len(viewer.content) > 100_000
    index = client.get("/")
    assert index.status_code == 200 and "handloop" in index.text
    assert client.get("/api/health").json() == {"status": "ok"}  # the API still wins over the catch-all mount
