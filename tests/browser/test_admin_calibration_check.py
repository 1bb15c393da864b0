"""The calibration check on the admin page (frontend/js/calibration_check.js), in a real browser on a live
stack: the samples annotated with the true keypoints, one camera's extrinsics then turned by 2 degrees in the
database; the admin picks the project, runs the check and sees that camera flagged and the others not."""

from __future__ import annotations

import uuid

import cv2
import numpy as np
import pytest
from sqlalchemy import select

from tests.browser.conftest import sign_in
from workers.capture import load_ground_truth, read_capture

pytestmark = [pytest.mark.browser]


def _annotate_all_from_truth(stack, frames) -> int:
    done = 0
    with stack.client("annotator") as http:
        while True:
            response = http.post("/api/annotate/next")
            if response.status_code != 200:
                return done
            task = response.json()
            gt = load_ground_truth(frames[task["frame_index"]])
            clicks = []
            for view in task["views"]:
                c = list(gt.camera_names).index(view["camera"])
                for k in task["keypoints_to_click"]:
                    x, y = gt.keypoints_2d[c, k]
                    clicks.append({"view_id": view["id"], "keypoint": k, "x": float(x), "y": float(y),
                                   "visibility": "visible"} if gt.visibility[c, k] else
                                  {"view_id": view["id"], "keypoint": k, "visibility": "not_annotated"})
            body = {"submission_id": uuid.uuid4().hex, "lease_token": task["lease_token"], "time_spent_s": 5.0,
                    "clicks": clicks}
            answer = http.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=body)
            assert answer.status_code == 201, answer.text
            done += 1


def test_the_admin_page_shows_the_calibration_check_and_flags_the_turned_camera(live_stack, tab):
    from backend.models.capture import CameraCalibration

    stack = live_stack(worker=False, frames=6)
    frames = read_capture(stack.capture_dir).sequences[0].frames
    assert _annotate_all_from_truth(stack, frames) == 6
    factory = stack.session_factory()
    with factory.begin() as session:
        row = session.execute(select(CameraCalibration).where(CameraCalibration.project_id == stack.project_id,
                                                              CameraCalibration.name == "cam3")).scalar_one()
        delta = cv2.Rodrigues(np.deg2rad(2.0) * np.array([[0.0], [1.0], [0.0]]))[0]
        row.R, row.t = (delta @ np.asarray(row.R)).tolist(), (delta @ np.asarray(row.t)).tolist()
    factory.kw["bind"].dispose()

    admin = tab()
    sign_in(admin, stack.base_url, stack.users["admin"].email, stack.users["admin"].password, "admin")
    page = admin.page
    page.wait_for_selector("#calibration-check form")
    assert page.locator("#calibration-check select option").all_inner_texts() == ["live"]
    page.click("#calibration-check button[type=submit]")
    page.wait_for_selector("#calibration-check table tbody tr[data-camera=cam3]")
    verdicts = {row.get_attribute("data-camera"): row.locator("td").last.inner_text()
                for row in page.locator("#calibration-check tbody tr").all()}
    assert verdicts == {f"cam{i}": "FLAGGED" if i == 3 else "ok" for i in range(8)}, verdicts
    text = page.inner_text("#calibration-check")
    assert "flagged: cam3" in text and "camera 'cam3'" in text and "6 annotated samples (clicks)" in text
    page.locator("#calibration-check").scroll_into_view_if_needed()
    admin.shot("admin-calibration-check")
    assert not admin.errors, admin.errors
