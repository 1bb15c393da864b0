"""Working-resolution copies of view images and masks in storage (capture format v2's `working_width_px`,
issue 18; the derivation and its conventions: workers/capture/working.py).

Images stay in storage at the cameras' full resolution (the stored copy, what exports and fits read).
A project imported with a working width narrower than a view gets that view shown at the working width,
and its networks and detector fed at it: a copy derived on first request, resized with area averaging and
kept in storage beside the original under `derived/w<width>/`, so a 2048 px capture loads in the browser
at, say, 640 px. Clicks and masks stay in full-resolution pixels: the page draws the copy scaled up to the
view's size; the job layer maps the networks' pixels back (workers/tasks/working_inputs.py).
"""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.capture import Project, Sample, Sequence, View
from backend.services.errors import NotFoundError
from backend.services.storage import Storage


def working_width(session: Session, view: View) -> int | None:
    """The width the view is shown at, or None when it is shown as stored (no working width, or a view
    no wider than it)."""
    width = session.execute(
        select(Project.working_width_px).join(Sequence, Sequence.project_id == Project.id)
        .join(Sample, Sample.sequence_id == Sequence.id).where(Sample.id == view.sample_id)).scalar_one_or_none()
    return int(width) if width is not None and width < view.width else None


def project_working_width(session: Session, project_id: int) -> int | None:
    """The project's working width (None: views are read as stored)."""
    width = session.execute(select(Project.working_width_px).where(Project.id == project_id)).scalar_one_or_none()
    return int(width) if width is not None else None


def _ensure(storage: Storage, key: str, make: object) -> str:
    """`key` when it is in storage, else written from `make()` first (concurrent callers may both derive it:
    the writes are atomic and the bytes the same)."""
    try:
        storage.etag(key)
        return key
    except NotFoundError:
        pass
    storage.put_bytes(key, make())  # type: ignore[operator]
    return key


def ensure_working_copy(storage: Storage, image_key: str, full_width: int, full_height: int, width: int) -> str:
    """The storage key of the image's working copy at `width` (derived now when missing)."""
    # deferred: the core's capture package loads OpenCV and PIL; the API's start-up stays free of them
    from workers.capture.working import derived_key, working_jpeg, working_size

    size = working_size(full_width, full_height, width)

    def make() -> bytes:
        try:
            return working_jpeg(storage.get_bytes(image_key), full_width, size, f"{image_key} in storage")
        except ValueError as exc:
            raise NotFoundError(str(exc)) from None

    return _ensure(storage, derived_key(image_key, width), make)


def ensure_working_mask(storage: Storage, mask_key: str, full_width: int, full_height: int, width: int) -> str:
    """The storage key of a mask's working copy at `width` (a PNG, derived now when missing)."""
    # deferred: as in ensure_working_copy
    from workers.capture.working import derived_key, working_mask_png, working_size

    size = working_size(full_width, full_height, width)

    def make() -> bytes:
        try:
            return working_mask_png(storage.get_bytes(mask_key), size, f"{mask_key} in storage")
        except ValueError as exc:
            raise NotFoundError(str(exc)) from None

    return _ensure(storage, derived_key(mask_key, width, ".png"), make)


def working_image_key(session: Session, storage: Storage, view: View) -> str:
    """The storage key of the image to show for `view`: the original, or its working-width copy."""
    width = working_width(session, view)
    if width is None:
        return view.image_key
    return ensure_working_copy(storage, view.image_key, view.width, view.height, width)
