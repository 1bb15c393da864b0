"""The labelling guidelines: read by everyone signed in (the annotate and review pages show them), edited by
admins (text, images with a caption). Edits carry the revision they were made on (409 when it moved on)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, File, Form, Path, UploadFile
from fastapi.responses import Response

from backend.api.deps import AdminUser, AnnotatorUser, SessionDep, StorageDep
from backend.schemas.guidelines import GuidelinesPublic, GuidelinesText
from backend.services.labeling import guidelines

router = APIRouter(tags=["guidelines"])
ImageId = Annotated[str, Path(pattern=r"^[0-9a-f]{32}$", description="An image's id (32 hex digits).")]
Revision = Annotated[int, Form(ge=0, le=2**31 - 1, description="The revision the edit was made on.")]


@router.get("/guidelines", response_model=GuidelinesPublic)
def read_guidelines(session: SessionDep, _user: AnnotatorUser) -> dict[str, Any]:
    return guidelines.read(session)


@router.get("/guidelines/images/{image_id}", response_class=Response, responses={404: {}})
def guideline_image(image_id: ImageId, session: SessionDep, storage: StorageDep, _user: AnnotatorUser) -> Response:
    key, content_type = guidelines.image_file(session, image_id)
    return Response(storage.get_bytes(key), media_type=content_type,
                    headers={"Cache-Control": "private, max-age=3600"})  # an image's id never names other bytes


@router.put("/admin/guidelines", response_model=GuidelinesPublic, responses={409: {}})
def save_guidelines(body: GuidelinesText, session: SessionDep, admin: AdminUser) -> dict[str, Any]:
    return guidelines.save_text(session, admin.id, body.text, body.revision)


@router.post("/admin/guidelines/images", response_model=GuidelinesPublic, status_code=201,
             responses={400: {}, 409: {}, 422: {}})
async def add_guideline_image(session: SessionDep, storage: StorageDep, admin: AdminUser, revision: Revision,
                              file: Annotated[UploadFile, File(description="PNG, JPEG, WebP or GIF, <= 5 MiB.")],
                              caption: Annotated[str, Form(max_length=500)] = "") -> dict[str, Any]:
    data = await file.read(guidelines.MAX_IMAGE_BYTES + 1)
    return guidelines.add_image(session, storage, admin.id, data, caption, revision)


@router.delete("/admin/guidelines/images/{image_id}", response_model=GuidelinesPublic, responses={404: {}, 409: {}})
def remove_guideline_image(image_id: ImageId, session: SessionDep, admin: AdminUser,
                           revision: int) -> dict[str, Any]:
    return guidelines.remove_image(session, admin.id, image_id, revision)
