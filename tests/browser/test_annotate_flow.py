"""Issue 38, item 13, on the real two-webcam recording (handpose3d, 720 px views with a 640 px working copy; read
from `$HANDLOOP_REALDATA_DIR`, else `<checkout>/../shared/realdata`; skipped when absent), in a real browser on a
live API: a view opens on the hand at a zoom that is not blocky and zooming past the working copy loads the
full-resolution pixels; an empty submit is not sent and an incomplete one asks first; "no hand here" per view
goes with the submission, "no hand" per sample and "skip" take a reason; a fit that fails is shown to its
annotator, and the sample goes to someone else (not back to them), shown there with why, its points kept."""

from __future__ import annotations

import pytest
from sqlalchemy import text

from tests.browser.conftest import SAMPLE, SCREEN_OF, VIEW_IDS, sign_in
from tests.support.live_stack import make_live_stack

pytestmark = [pytest.mark.browser, pytest.mark.slow]

FRAMES = (56, 182, 308)  # three frames of the recording with the hand in both views


@pytest.fixture(scope="module")
def real_capture(tmp_path_factory):
    from backend.bench.realdata import RealDataMissingError, handpose3d_cameras, link_handpose3d_videos
    from workers.capture.assemble import assemble_capture

    try:
        cameras = handpose3d_cameras()
    except RealDataMissingError as exc:
        pytest.skip(f"the real recording is absent: {exc}")
    root = tmp_path_factory.mktemp("handpose3d")
    videos = link_handpose3d_videos(root / "videos")
    out = root / "capture"
    assemble_capture(cameras, out, videos=videos, offsets={c.name: FRAMES[0] for c in cameras}, every=126,
                     name="handpose3d", workers=1)
    return out


@pytest.fixture
def real_stack(tmp_path, real_capture, request):
    stack = make_live_stack(tmp_path / "data", real_capture, worker=getattr(request, "param", False))
    yield stack
    stack.stop()


def _rows(stack, sql: str, **params) -> list:
    with stack.session_factory()() as session:
        return session.execute(text(sql), params).all()


def _open(t, stack, role: str = "annotator") -> None:
    user = stack.users[role]
    # A reviewer lands on the (here empty) review queue.
    sign_in(t, stack.base_url, user.email, user.password, "annotate" if role == "annotator" else "review-empty")
    if role != "annotator":  # a reviewer lands on the review page; they may annotate too
        t.page.goto(stack.base_url + "/#/annotate")
        t.page.wait_for_selector("body[data-ready=annotate]", state="attached", timeout=60_000)


def test_views_open_on_the_hand_unblocky_and_zoom_loads_full_resolution(real_stack, tab):
    import json

    t = tab()
    page = t.page

    def with_pre_annotation(route) -> None:
        # A pre-annotation fit of a hand at the image's right edge, as the recording's last frames show it.
        response = route.fetch()
        body = response.json()
        points = [[680.0 + 35.0 * (k % 5) / 4, 330.0 + 3.0 * k] for k in range(21)]
        body["sources"] = [{"kind": "fit", "label": "fit 1 (test)", "confidences": [0.9] * 21,
                            "views": {str(c["view_id"]): points for c in body["cameras"]}}]
        route.fulfill(response=response, body=json.dumps(body))

    page.route("**/proposals", with_pre_annotation)
    _open(t, real_stack)
    view = page.evaluate("() => { const p = window.__handloop.page; return {w: p.view.width,"
                         " copy: p.view.image.width, scale: p.vp.scale, full: Boolean(p.view.fullImage)}; }")
    assert view["w"] == 720 and view["copy"] == 640, view
    # At most 2 screen px per working-copy pixel (the 640 px copies opened at 243-483 % before).
    assert view["scale"] * view["w"] / view["copy"] <= 2.0 + 1e-9, view
    # No blank beyond the image's edge (the hand at the edge opened as a strip of arm beside empty canvas).
    box = page.evaluate("""() => { const p = window.__handloop.page; const r = p.canvas.getBoundingClientRect();
        const [x0, y0] = p.vp.toImage(0, 0), [x1, y1] = p.vp.toImage(r.width, r.height);
        return [x0, y0, x1, y1, p.view.width, p.view.height]; }""")
    x0, y0, x1, y1, w, h = box
    for lo, hi, size in ((x0, x1, w), (y0, y1, h)):
        if hi - lo <= size:  # the canvas shows part of the image along this axis: all of it image
            assert lo >= -0.5 - 1e-6 and hi <= size - 0.5 + 1e-6, box
        else:  # the whole image along this axis, centred
            assert lo <= -0.5 and hi >= size - 0.5, box
    # The hand is on screen.
    hx, hy = page.evaluate(SCREEN_OF, [697.0, 360.0])
    canvas = page.locator("canvas.main-canvas").bounding_box()
    assert canvas["x"] <= hx <= canvas["x"] + canvas["width"] and canvas["y"] <= hy <= canvas["y"] + canvas["height"]
    for _ in range(6):
        page.keyboard.press("+")
    page.wait_for_function("() => { const v = window.__handloop.page.view; return v.fullImage &&"
                           " v.fullImage.width === v.width; }", timeout=30_000)
    page.wait_for_function("() => !window.__handloop.page.frame")
    assert not t.errors, t.errors
    t.shot("annotate-real-full-resolution")


def test_empty_submit_is_not_sent_incomplete_asks_and_no_hand_or_skip_take_a_reason(real_stack, tab):
    stack = real_stack
    t = tab()
    page = t.page
    _open(t, stack)
    first = page.evaluate(SAMPLE)
    views = page.evaluate(VIEW_IDS)

    # Nothing placed: Ctrl+Enter sends nothing and says why (it was accepted, and its fit failed).
    page.keyboard.press("Control+Enter")
    assert page.evaluate("() => document.body.dataset.ask") == "empty"
    assert "nothing to fit" in page.inner_text(".ask")
    page.keyboard.press("Escape")
    assert page.evaluate("() => document.body.dataset.ask") is None
    # The API refuses an all-"not annotated" submission too.
    with stack.client("annotator") as http:
        token = http.post("/api/annotate/next").json()["lease_token"]
        refused = http.post(f"/api/annotate/samples/{first}/submissions", json={
            "submission_id": "empty-submission-1", "lease_token": token, "time_spent_s": 1.0,
            "clicks": [{"view_id": v, "keypoint": 0, "visibility": "not_annotated"} for v in views]})
    assert refused.status_code == 422 and "nothing to fit" in refused.text, refused.text

    # No hand in view 1 (X); two points in view 2: Ctrl+Enter asks first (10 points not set), Esc keeps working.
    page.keyboard.press("x")
    assert page.evaluate("() => document.body.dataset.noHand.split(' ').filter(Boolean).map(Number)") == [views[0]]
    page.click(".thumb >> nth=1")
    box = page.locator("canvas.main-canvas").bounding_box()
    for key, dx in (("1", -40), ("3", 40)):  # wrist and index tip, anywhere on the image
        page.keyboard.press(key)
        page.mouse.click(box["x"] + box["width"] / 2 + dx, box["y"] + box["height"] / 2)
    page.keyboard.press("Control+Enter")
    assert page.evaluate("() => document.body.dataset.ask") == "submit"
    assert "4 point(s) not set in 1 view(s)" in page.inner_text(".ask"), page.inner_text(".ask")
    page.keyboard.press("Escape")
    assert _rows(stack, "SELECT id FROM submissions") == []
    page.keyboard.press("Control+Enter")
    page.keyboard.press("Control+Enter")  # again: submit as is
    page.wait_for_function(f"() => document.body.dataset.sample !== '{first}'", timeout=30_000)
    assert _rows(stack, "SELECT sample_id, view_id, kind FROM annotation_flags") == [(first, views[0], "no_hand_view")]
    placed = _rows(stack, "SELECT view_id, keypoint FROM clicks WHERE sample_id = :s AND visibility = 'visible'",
                   s=first)
    assert sorted(placed) == [(views[1], 0), (views[1], 8)], placed

    # The second sample skipped with a reason: back in the queue, never served to this annotator again.
    second = page.evaluate(SAMPLE)
    page.click(".side .skip-sample")
    assert page.evaluate("() => document.body.dataset.ask") == "skip"
    page.click(".ask .confirm-pass")  # no reason: refused on the page
    assert page.evaluate(SAMPLE) == second
    page.fill(".ask .pass-reason", "the fingers are blurred in both views")
    page.click(".ask .confirm-pass")
    page.wait_for_function(f"() => document.body.dataset.sample !== '{second}'", timeout=30_000)
    third = page.evaluate(SAMPLE)
    assert third not in (first, second)
    assert _rows(stack, "SELECT state, leased_by_id FROM samples WHERE id = :s", s=second) == [
        ("needs_annotation", None)]
    # The third: no hand in any view; the page offers it from the empty-submit question too.
    page.keyboard.press("Control+Enter")
    page.click(".ask .no-hand-sample")
    assert page.input_value(".ask .pass-reason") == "no hand in any view"
    page.click(".ask .confirm-pass")
    page.wait_for_selector("body[data-ready=annotate-empty]", state="attached", timeout=30_000)
    assert _rows(stack, "SELECT state FROM samples WHERE id = :s", s=third) == [("rejected",)]
    flags = _rows(stack, "SELECT sample_id, kind, reason FROM annotation_flags WHERE view_id IS NULL ORDER BY id")
    assert flags == [(second, "skip", "the fingers are blurred in both views"),
                     (third, "no_hand", "no hand in any view")], flags
    # Someone else is given the skipped sample.
    with stack.client("reviewer") as http:
        assert http.post("/api/annotate/next").json()["sample_id"] == second
    assert not t.errors, t.errors


@pytest.mark.parametrize("real_stack", [True], indirect=True)
def test_a_failed_fit_is_shown_and_the_sample_goes_to_someone_else(real_stack, tab):
    stack = real_stack
    t = tab()
    page = t.page
    _open(t, stack)
    first = page.evaluate(SAMPLE)
    # A mask corrected, no point placed (every point goes as not annotated): the fit has nothing to fit.
    page.keyboard.press("b")
    box = page.locator("canvas.main-canvas").bounding_box()
    cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(cx, cy)
    page.mouse.down()
    page.mouse.move(cx + 60, cy + 20, steps=6)
    page.mouse.up()
    page.keyboard.press("p")
    page.keyboard.press("Control+Enter")
    assert page.evaluate("() => document.body.dataset.ask") == "submit"
    page.keyboard.press("Control+Enter")
    page.wait_for_function(f"() => document.body.dataset.sample !== '{first}'", timeout=30_000)
    # The page says the fit failed, and why (it showed only "last: sample 1 -> fit job 41" before).
    page.wait_for_selector(".side .fit-failures", timeout=240_000)
    assert "nothing to fit" in page.inner_text(".side .fit-failures")
    assert "failed: " in page.inner_text(".side .last-submission")
    assert _rows(stack, "SELECT sample_id, kind FROM annotation_flags") == [(first, "fit_failed")]

    # This annotator is not given the sample again; someone else is, with the failure shown on their page.
    with stack.client("annotator") as http:
        held = {http.post("/api/annotate/next").json()["sample_id"]}
    assert first not in held
    other = tab()
    _open(other, stack, "reviewer")
    assert other.page.evaluate(SAMPLE) == first
    assert "nothing to fit" in other.page.inner_text(".side .fit-failure-here")
    assert not t.errors and not other.errors, (t.errors, other.errors)


def test_the_detector_ring_is_drawn_beside_a_confident_fit(real_stack, tab):
    """A pre-annotation's sources as the API sends them (the fit, carrying its agreement as confidence, then
    the detector): Enter takes the confident F points; where the detector's own point lies apart from the fit's,
    a D ring shows it (listed in the panel) and a click on it takes the detector's point."""
    import json

    t = tab()
    page = t.page
    fit_conf = {0: 0.9, 4: 0.9, 8: 0.9, 12: 0.9, 16: 0.9, 20: 0.4}

    def with_pre_annotation(route) -> None:
        response = route.fetch()
        body = response.json()
        fit, det = {}, {}
        for camera in body["cameras"]:
            points = [[300.0 + 4 * k, 360.0] for k in range(21)]
            fit[str(camera["view_id"])] = points
            det[str(camera["view_id"])] = [[x + (8.0 if k == 20 else 0.5), y] for k, (x, y) in enumerate(points)]
        body["sources"] = [
            {"kind": "fit", "label": "fit 1 (test)", "confidences": [fit_conf.get(k, 0.9) for k in range(21)],
             "views": fit},
            {"kind": "detector", "label": "detector (confidence 0.45)", "confidences": [0.8] * 21, "views": det}]
        route.fulfill(response=response, body=json.dumps(body))

    page.route("**/proposals", with_pre_annotation)
    _open(t, real_stack)
    rings = page.evaluate("() => { const p = window.__handloop.page;"
                          " return [...p.alternates.get(p.view.id).entries()].map(([k, a]) => [k, a.x, a.y]); }")
    assert rings == [[20, 388.0, 360.0]], rings  # only where the detector lies apart (8 px; not 0.5 px)
    assert "D 0.80 8 px away" in page.inner_text(".kp-list")
    page.keyboard.press("Enter")  # the five confident F points; the pinky (F 0.40) is left for a look
    got = page.evaluate("() => { const p = window.__handloop.page; return [0, 4, 8, 12, 16, 20].map((k) => {"
                        " const c = p.annotation.get(p.view.id, k); return c && c.from; }); }")
    assert got == ["fit", "fit", "fit", "fit", "fit", None], got
    at = page.evaluate(SCREEN_OF, [388.0, 360.0])
    page.mouse.click(*at)  # the D ring
    # (the view is then complete: the page moves on to the next one)
    pinky = page.evaluate("() => { const p = window.__handloop.page; return p.annotation.get(p.views[0].id, 20); }")
    assert pinky["from"] == "detector" and pinky["x"] == 388.0, pinky
    assert not t.errors, t.errors
