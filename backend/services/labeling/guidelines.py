"""The project's labelling guidelines (text and images an admin edits; every signed-in person reads them on
the annotate and review pages). One row, saved with the revision it was edited from: a save made on an older
revision is refused (409) so one admin never silently overwrites another's."""

from __future__ import annotations

import io
import secrets
from typing import Any

from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.models.guidelines import Guidelines
from backend.services import audit
from backend.services.captures.storage import Storage
from backend.services.errors import ConflictError, InvalidInputError, NotFoundError

ROW_ID = 1
MAX_TEXT = 50_000
MAX_IMAGES = 20
MAX_IMAGE_BYTES = 5 * 1024 * 1024
IMAGE_FORMATS = {"PNG": "image/png", "JPEG": "image/jpeg", "WEBP": "image/webp", "GIF": "image/gif"}


def read(session: Session) -> dict[str, Any]:
    """The guidelines as shown: text, images (id, caption, content type), revision (0: never saved)."""
    row = session.get(Guidelines, ROW_ID)
    if row is None:
        return {"text": "", "images": [], "revision": 0, "updated_at": None, "updated_by_id": None}
    return {"text": row.text, "images": [_public(i) for i in row.images], "revision": row.revision,
            "updated_at": row.updated_at, "updated_by_id": row.updated_by_id}


def _public(image: dict[str, Any]) -> dict[str, Any]:
    return {"id": image["id"], "caption": image["caption"], "content_type": image["content_type"]}


def _row_at(session: Session, revision: int) -> Guidelines:
    """The row to change, locked, after checking it is still at `revision` (the one the admin edited)."""
    row = session.get(Guidelines, ROW_ID, with_for_update=True)
    if row is None:
        row = Guidelines(id=ROW_ID, text="", images=[], revision=0, updated_at=utcnow())
        session.add(row)
    if row.revision != revision:
        raise ConflictError(f"the guidelines were saved by someone else meanwhile (revision {row.revision}, you "
                            f"edited revision {revision}); reload them, then make your change again")
    return row


def _saved(session: Session, row: Guidelines, actor_id: int | None, action: str, **data: Any) -> dict[str, Any]:
    row.revision += 1
    row.updated_by_id = actor_id
    row.updated_at = utcnow()
    audit.record(session, actor_id, action, "guidelines", ROW_ID, revision=row.revision, **data)
    session.flush()
    return read(session)


def save_text(session: Session, actor_id: int | None, text: str, revision: int) -> dict[str, Any]:
    if len(text) > MAX_TEXT:
        raise InvalidInputError(f"the guidelines' text holds {len(text)} characters; at most {MAX_TEXT}")
    row = _row_at(session, revision)
    row.text = text
    return _saved(session, row, actor_id, "guidelines.text", characters=len(text))


def add_image(session: Session, storage: Storage, actor_id: int | None, data: bytes, caption: str,
              revision: int) -> dict[str, Any]:
    """Store an image (PNG, JPEG, WebP or GIF, at most 5 MiB) after the others; 422 for anything else."""
    if len(data) > MAX_IMAGE_BYTES:
        raise InvalidInputError(f"the image has {len(data)} bytes; at most {MAX_IMAGE_BYTES} (5 MiB)")
    from PIL import Image, UnidentifiedImageError  # deferred: Pillow only for an upload, not at the API's start-up

    try:
        with Image.open(io.BytesIO(data)) as image:
            kind = image.format
            image.verify()
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise InvalidInputError(f"the file is not an image this page can show ({exc}); upload a PNG, JPEG, WebP "
                                "or GIF") from exc
    if kind not in IMAGE_FORMATS:
        raise InvalidInputError(f"{kind} images are not shown; upload a PNG, JPEG, WebP or GIF")
    row = _row_at(session, revision)
    if len(row.images) >= MAX_IMAGES:
        raise InvalidInputError(f"the guidelines hold {MAX_IMAGES} images already; delete one first")
    image_id = secrets.token_hex(16)
    key = f"guidelines/{image_id}.{kind.lower()}"
    storage.put_bytes(key, data)
    row.images = [*row.images, {"id": image_id, "key": key, "caption": caption,
                                "content_type": IMAGE_FORMATS[kind]}]
    return _saved(session, row, actor_id, "guidelines.image_add", image=image_id)


def remove_image(session: Session, actor_id: int | None, image_id: str, revision: int) -> dict[str, Any]:
    row = _row_at(session, revision)
    if not any(i["id"] == image_id for i in row.images):
        raise NotFoundError(f"the guidelines have no image {image_id}")
    row.images = [i for i in row.images if i["id"] != image_id]
    return _saved(session, row, actor_id, "guidelines.image_remove", image=image_id)


def image_file(session: Session, image_id: str) -> tuple[str, str]:
    """(storage key, content type) of one of the guidelines' images; 404 when it is not one."""
    row = session.get(Guidelines, ROW_ID)
    for image in row.images if row else []:
        if image["id"] == image_id:
            return image["key"], image["content_type"]
    raise NotFoundError(f"the guidelines have no image {image_id}")
