"""The 3D view's recording of one sample, for viser's client embedded in the review page.

viser's client fetches `?playbackPath=` itself and cannot send the bearer token, so this route takes a
short-lived scene ticket instead (issued with the review overlay, services.display.scene_tickets)."""

from __future__ import annotations

from fastapi import APIRouter, Query, Request, Response

from backend.api.deps import SessionDep, SettingsDep, StorageDep
from backend.schemas.base import Id
from backend.services.display import scene_tickets, scenes
from backend.services.errors import AuthError

router = APIRouter(prefix="/viewer", tags=["3D viewer"])


@router.get("/samples/{sample_id}/scene", response_class=Response,
            responses={200: {"content": {"application/octet-stream": {}}}, 304: {}, 401: {}, 403: {}})
def sample_scene(sample_id: Id, request: Request, session: SessionDep, settings: SettingsDep, storage: StorageDep,
                 ticket: str = Query(default="", max_length=400, description="From the review overlay.")) -> Response:
    """The sample's scene (mesh, skeleton, keypoints, camera frustums with their images) as a `.viser`
    recording."""
    if not ticket:
        raise AuthError("a scene ticket is needed: open the 3D view from the review page")
    parsed = scenes.authorise(session, settings.signing_key, ticket, sample_id)
    fit = scenes.load_fit(session, sample_id, parsed.fit_id)
    etag = scenes.etag_of(fit)
    headers = {"ETag": etag, "Cache-Control": f"private, max-age={scene_tickets.TICKET_SECONDS}"}
    if request.headers.get("if-none-match") == etag:
        return Response(status_code=304, headers=headers)
    data = scenes.scene_bytes(session, storage, fit, settings.mano_path)
    return Response(data, media_type="application/octet-stream", headers=headers)
