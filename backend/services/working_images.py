"""Working-resolution copies of view images (capture format v2's `working_width_px`, issue 18).

Images stay in storage at the cameras' full resolution (the stored copy, what exports and fits read).
A project imported with a working width narrower than a view gets that view shown at the working width:
a copy derived on first request, resized with area averaging and kept in storage beside the original
under `derived/w<width>/`, so a 2048 px capture loads in the browser at, say, 1024 px. Clicks and masks
stay in full-resolution pixels: the page draws the copy scaled up to the view's size.
"""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.capture import Project, Sample, Sequence, View
from backend.services.errors import NotFoundError
from backend.services.storage import Storage

DERIVED_PREFIX = "derived"
JPEG_QUALITY = 92


def working_width(session: Session, view: View) -> int | None:
    """The width the view is shown at, or None when it is shown as stored (no working width, or a view
    no wider than it)."""
    width = session.execute(
        select(Project.working_width_px).join(Sequence, Sequence.project_id == Project.id)
        .join(Sample, Sample.sequence_id == Sequence.id).where(Sample.id == view.sample_id)).scalar_one_or_none()
    return int(width) if width is not None and width < view.width else None


def working_size(view_width: int, view_height: int, width: int) -> tuple[int, int]:
    """(width, height) of the working copy: the view's aspect ratio kept (workers.geometry.Camera.scaled)."""
    return width, max(1, round(view_height * width / view_width))


def derived_key(image_key: str, width: int) -> str:
    stem = image_key.rsplit(".", 1)[0]
    return f"{DERIVED_PREFIX}/w{width}/{stem}.jpg"


def working_image_key(session: Session, storage: Storage, view: View) -> str:
    """The storage key of the image to show for `view`: the original, or its working-width copy (derived
    now when it is not in storage yet; concurrent requests may both derive it, the writes are atomic)."""
    width = working_width(session, view)
    if width is None:
        return view.image_key
    key = derived_key(view.image_key, width)
    try:
        storage.etag(key)
        return key
    except NotFoundError:
        pass
    size = working_size(view.width, view.height, width)
    storage.put_bytes(key, _resized_jpeg(storage.get_bytes(view.image_key), view.width, size, view.image_key))
    return key


def _resized_jpeg(data: bytes, full_width: int, size: tuple[int, int], what: str) -> bytes:
    import cv2  # deferred: the API's start-up stays free of OpenCV
    import numpy as np

    # A JPEG decoded at 1/2, 1/4 or 1/8 scale (libjpeg's DCT scaling) where that stays at least the working
    # width: 2048 -> 1024 px for a 640 px copy decodes ~2.7x faster than in full (425 vs 160 ms loaded).
    flag = cv2.IMREAD_COLOR
    for factor, reduced in ((8, cv2.IMREAD_REDUCED_COLOR_8), (4, cv2.IMREAD_REDUCED_COLOR_4),
                            (2, cv2.IMREAD_REDUCED_COLOR_2)):
        if full_width // factor >= size[0]:
            flag = reduced
            break
    image = cv2.imdecode(np.frombuffer(data, np.uint8), flag)
    if image is None:
        raise NotFoundError(f"image {what!r} in storage cannot be decoded")
    resized = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    ok, encoded = cv2.imencode(".jpg", resized, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise NotFoundError(f"image {what!r}: its working-width copy could not be encoded")
    return encoded.tobytes()
