"""A bootstrap round on 2048 px views with a 320 px working width (issue 18), on the embedded worker: both
networks train on the working copies, predict on them, and HandSegNet's masks are stored at the views' full
size (the prediction is recorded only when its masks fit the 2048 px views); the copies are derived once, in
storage beside the originals, by the job layer (nothing else asked for them here)."""

from __future__ import annotations

import cv2
import pytest
from sqlalchemy import select

from tests.support.live_stack import tiny_capture
from tests.support.real_sized import FULL_WIDTH, upscaled_capture
from tests.workers.tasks.test_round_live import check_round, run_round
from workers.capture.working import DERIVED_PREFIX

pytestmark = pytest.mark.slow

WORKING_WIDTH = 320


def test_a_round_on_real_sized_views_reads_the_working_copies(live_stack, capture_cache, tmp_path):
    from backend.models.capture import View
    from backend.models.enums import MaskKind
    from backend.models.labels import Mask
    from tests.support.live_stack import make_live_stack

    small = tiny_capture(capture_cache, frames=6, width=160)
    capture = upscaled_capture(small, capture_cache / f"{small.name}-{FULL_WIDTH}px-w{WORKING_WIDTH}",
                               working_width_px=WORKING_WIDTH)
    stack = make_live_stack(tmp_path / "data", capture, queue_for_annotation=False)
    try:
        check_round(stack, run_round(stack))
        with stack.session_factory()() as session:
            views = session.execute(select(View.image_key, View.width, View.height)).all()
            predicted = session.execute(select(Mask.storage_key).where(Mask.kind == MaskKind.predicted)).scalars().all()
        storage = stack.settings.storage_dir
        derived = {p.relative_to(storage / DERIVED_PREFIX / f"w{WORKING_WIDTH}").with_suffix("").as_posix()
                   for p in (storage / DERIVED_PREFIX / f"w{WORKING_WIDTH}").rglob("*.jpg")}
        assert derived == {key.rsplit(".", 1)[0] for key, _, _ in views}  # every view, once
        for key in list(derived)[:4]:
            copy = cv2.imread(str(storage / DERIVED_PREFIX / f"w{WORKING_WIDTH}" / f"{key}.jpg"))
            assert copy.shape[1] == WORKING_WIDTH
        assert predicted, "no HandSegNet mask was recorded"
        sizes = {(w, h) for _, w, h in views}
        for key in predicted:
            mask = cv2.imread(str(storage / key), cv2.IMREAD_GRAYSCALE)
            assert (mask.shape[1], mask.shape[0]) in sizes and mask.shape[1] == FULL_WIDTH
    finally:
        stack.stop()
