"""Images and masks, for any signed-in user, with validators so browsers revalidate cheaply."""

from __future__ import annotations

import mimetypes

from fastapi import APIRouter, Query, Request, Response

from backend.api.deps import AnnotatorUser, SessionDep, SettingsDep, StorageDep
from backend.schemas.base import Id
from backend.services.captures.samples import get_mask, get_view
from backend.services.captures.working_images import working_image_key

router = APIRouter(prefix="/files", tags=["files"])


def _serve(request: Request, storage: StorageDep, key: str, max_age_s: int) -> Response:
    etag = f'"{storage.etag(key)}"'
    headers = {"ETag": etag, "Cache-Control": f"private, max-age={max_age_s}"}
    if request.headers.get("if-none-match") == etag:
        return Response(status_code=304, headers=headers)
    media_type = mimetypes.guess_type(key)[0] or "application/octet-stream"
    return Response(storage.get_bytes(key), media_type=media_type, headers=headers)


@router.get("/views/{view_id}/image", response_class=Response,
            responses={200: {"content": {"image/png": {}, "image/jpeg": {}}}, 304: {}})
def view_image(view_id: Id, request: Request, session: SessionDep, settings: SettingsDep, storage: StorageDep,
               _user: AnnotatorUser,
               full: bool = Query(False, description="The full-resolution original even where the project has a "
                                  "narrower working width (the default image is then the working-width copy).")
               ) -> Response:
    view = get_view(session, view_id)
    key = view.image_key if full else working_image_key(session, storage, view)
    return _serve(request, storage, key, settings.image_cache_seconds)


@router.get("/masks/{mask_id}", response_class=Response, responses={200: {"content": {"image/png": {}}}, 304: {}})
def mask_image(mask_id: Id, request: Request, session: SessionDep, settings: SettingsDep, storage: StorageDep,
               _user: AnnotatorUser) -> Response:
    # Mask versions are immutable: a new correction is a new id.
    return _serve(request, storage, get_mask(session, mask_id).storage_key, settings.image_cache_seconds)
