"""The reviewers' 3D scenes: a ticket (services.display.scene_tickets) opens one sample's recording, built once
per fit (fits never change; the key includes the fit's creation time) and kept in a small per-process cache."""

from __future__ import annotations

import threading
from collections import OrderedDict
from pathlib import Path

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session, undefer

from backend.models.capture import View
from backend.models.enums import Role
from backend.models.fits import Fit, Prediction
from backend.services.accounts.users import load_principal
from backend.services.captures.storage import Storage
from backend.services.display import scene_tickets
from backend.services.display.overlays import end_reads
from backend.services.display.view_geometry import view_cameras
from backend.services.errors import AuthError, NotFoundError, PermissionDeniedError
from backend.viewer.hand_mesh import fit_mesh, fit_side, hand_model_label, load_arrays
from backend.viewer.scene import SampleScene, record_scene, scene_camera, thumbnail

CACHE_ENTRIES = 32
SCENE_VERSION = 1  # bump when the scene's content changes, so browsers drop cached recordings
_cache: OrderedDict[str, bytes] = OrderedDict()
_cache_lock = threading.Lock()


def _cached(key: str) -> bytes | None:
    with _cache_lock:
        data = _cache.get(key)
        if data is not None:
            _cache.move_to_end(key)
        return data


def _remember(key: str, data: bytes) -> None:
    with _cache_lock:
        _cache[key] = data
        while len(_cache) > CACHE_ENTRIES:
            _cache.popitem(last=False)


def authorise(session: Session, secret_key: str, ticket: str, sample_id: int) -> scene_tickets.SceneTicket:
    """The ticket's contents if it is valid for this sample and its user may still review."""
    parsed = scene_tickets.verify(secret_key, ticket, sample_id)
    user = load_principal(session, parsed.user_id)
    if user is None or not user.is_active:
        raise AuthError("the account this scene ticket was issued to is gone or deactivated")
    if user.token_version != parsed.token_version:
        raise AuthError("scene ticket revoked (the account's password, role or state changed); reload the review page")
    if Role(user.role).rank < Role.reviewer.rank:
        raise PermissionDeniedError(f"the 3D view needs the reviewer role; you are {user.role}")
    return parsed


def load_fit(session: Session, sample_id: int, fit_id: int) -> Fit:
    fit = session.get(Fit, fit_id, options=[undefer(Fit.vertices_f32)])
    if fit is None or fit.sample_id != sample_id:
        raise NotFoundError(f"fit {fit_id} of sample {sample_id} not found")
    return fit


def _key(fit: Fit) -> str:
    return f"{fit.id}-{int(fit.created_at.timestamp() * 1e6)}-v{SCENE_VERSION}"


def etag_of(fit: Fit) -> str:
    return f'"scene-{_key(fit)}"'


def scene_bytes(session: Session, storage: Storage, fit: Fit, mano_path: Path | None = None) -> bytes:
    """The `.viser` recording of a fit's sample."""
    key = _key(fit)
    cached = _cached(key)
    if cached is not None:
        return cached

    prediction = session.get(Prediction, fit.prediction_id) if fit.prediction_id else None
    keys = dict(session.execute(select(View.id, View.image_key).where(View.sample_id == fit.sample_id)).all())
    views = view_cameras(session, fit.sample_id)
    end_reads(session)
    arrays = load_arrays(fit.model_file, mano_path, fit_side(fit.diagnostics))
    mesh = fit_mesh(arrays, fit.params, fit.vertices_f32) if arrays is not None else None
    cameras = [scene_camera(c.name, c.width, c.height, c.K, c.R, c.t, thumbnail(storage.get_bytes(keys[c.view_id])))
               for c in views]
    content = SampleScene(vertices=None if mesh is None else mesh.vertices, faces=None if mesh is None else mesh.faces,
                          keypoints=np.asarray(fit.keypoints_m, float),
                          prediction=None if prediction is None else np.asarray(prediction.keypoints_m, float),
                          cameras=cameras, label=hand_model_label(fit.model_file))
    data = record_scene(content)
    _remember(key, data)
    return data
