"""Working-resolution copies of view images and masks in storage (capture format v2's `working_width_px`,
issue 18; the derivation and its conventions: workers/capture/working.py).

Images stay in storage at the cameras' full resolution (the stored copy, what exports and fits read).
A project imported with a working width narrower than a view gets that view shown at the working width,
and its networks and detector fed at it: a copy derived on first request, resized with area averaging and
kept in storage beside the original under `derived-v2/w<width>/`, so a 2048 px capture loads in the browser
at, say, 640 px. Clicks and masks stay in full-resolution pixels: the page draws the copy scaled up to the
view's size; the job layer maps the networks' pixels back (workers/tasks/working_inputs.py).
"""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.capture import Project, Sample, Sequence, View
from backend.services.captures.storage import Storage
from backend.services.errors import NotFoundError


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


def ensure_working_copy(storage: Storage, key: str, full_width: int, full_height: int, width: int,
                        mask: bool = False) -> str:
    """The storage key of the working copy at `width` of the image (a JPEG) or, `mask`, the 8-bit mask (a PNG)
    at `key` in storage: derived now when missing or older than the original (an original rewritten under
    the same key, e.g. storage outliving a recreated database). Concurrent callers may both derive it: the
    writes are atomic and the bytes the same. NotFoundError when the original is missing or undecodable."""
    # deferred: the core's capture package loads OpenCV and PIL; the API's start-up stays free of them
    from workers.capture.working import derived_key, working_jpeg, working_mask_png, working_size

    size = working_size(full_width, full_height, width)
    target = derived_key(key, width, ".png" if mask else ".jpg")
    original_ns = storage.mtime_ns(key)
    try:
        if storage.mtime_ns(target) >= original_ns:
            return target
    except NotFoundError:
        pass
    data, what = storage.get_bytes(key), f"{key} in storage"
    try:
        copy = working_mask_png(data, size, what) if mask else working_jpeg(data, (full_width, full_height), size, what)
    except ValueError as exc:
        raise NotFoundError(str(exc)) from None
    storage.put_bytes(target, copy)
    return target


def working_image_key(session: Session, storage: Storage, view: View) -> str:
    """The storage key of the image to show for `view`: the original, or its working-width copy."""
    width = working_width(session, view)
    if width is None:
        return view.image_key
    return ensure_working_copy(storage, view.image_key, view.width, view.height, width)
