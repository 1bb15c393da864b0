"""`handloop bench ui`: the browser UI's speed in a real browser (Debian's headless Chromium, Playwright).

On a fresh data folder with a synthetic capture at 1280 px (views of 1280x1024 and 1280x960) served by
the real API process (`backend.runtime.start_stack`, no worker: the fits under review are recorded from
the capture's ground truth, as a worker would record them, since UI speed does not depend on who fitted):

- interactive_ms: navigation start -> page interactive (task drawn, keys bound), for the annotate, review
  and admin pages, each a first visit (empty cache) in a new browser context on a warm server; the slowest
  page, median of runs. The very first load of each page after the server started is reported apart
  (`interactive_first_after_start_ms`: it pays the server's one-off imports of OpenCV, SciPy and viser).
- next_sample_ms: review page, one key press ("a", accept) -> the next sample painted (the frame after it
  was drawn), with the next sample prefetched as in normal use; median over the decisions (max reported),
  with the 3D view hidden (`V`); the same with the 3D view open is reported apart, since headless Chromium
  renders viser's WebGL scene in software (SwiftShader) on the same CPU.
- brush_event_ms: annotate page, brush on a 1280x1024 view: one pointer event handled (mask bits, overlay
  upload of the changed rectangle) and the view redrawn; mean over the events (p95 and max reported).
- scripted annotator working from proposals, per sample: pointer clicks, key presses and wall seconds
  (no think time: what the UI itself asks of a person and costs), twice: from its own clicks' triangulation
  ("T": wrist and tips clicked by hand in two views, Enter in the others) and from a network's proposals
  ("M": an MVNet-like source injected into the proposals answer, the true keypoints with 3 px noise,
  one in five below the accept threshold; Enter in every view). Either way, every accepted point more than
  4 px from the truth is corrected by hand (pick, Del, click), so the result is as good as all-clicked.
- scripted annotator marking occlusion from proposals ("O"): a network's proposals (the true keypoints with 3 px
  noise, all confident) and the fit's flags of the keypoints its mesh hides per view (computed as the API
  computes them, `overlays.mesh_hidden`, for the true hand) injected into the proposals answer; Enter in every
  view, every point more than 4 px off dragged into place, then every keypoint inside the image whose visibility
  differs from the truth flipped (digit, O). Reported: clicks, keys and wall seconds per sample, the
  truly occluded keypoints, and the actions spent on occlusion per occluded keypoint (target <= 1; accepting
  all as visible and flipping each costs 2).
- activity events rejected: every activity log the pages posted during the run (annotate and review), the
  logs the API refused (4xx/5xx) and the actions in them (target 0).
- never losing work: clicks lost by a reload, by the Back button and by a lapsed lease on a free sample
  (targets 0), and restore_ms: navigation start of the reload -> the draft applied on screen.
"""

from __future__ import annotations

import json
import logging
import shutil
import statistics
import sys
import time
import uuid
from datetime import timedelta
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from sqlalchemy import text

from backend.db.base import utcnow
from backend.db.migrate import upgrade
from backend.db.session import create_engine_from_url, make_session_factory
from backend.models.enums import Role
from backend.runtime import start_stack
from backend.services.accounts.users import create_user
from backend.services.captures.importer import import_capture
from backend.services.captures.storage import LocalDiskStorage
from backend.services.display.overlays import mesh_hidden
from backend.services.display.view_geometry import ViewCamera
from backend.services.review.verification import HeuristicThresholds
from backend.settings import Settings
from backend.viewer.hand_mesh import load_arrays
from workers.capture import load_ground_truth, read_capture
from workers.handmodel.builtin import build_builtin_hand, cache
from workers.handmodel.posed import posed_mesh
from workers.synth.generator import generate_capture
from workers.synth.plan import SynthConfig
from workers.tasks import records

logger = logging.getLogger("handloop.bench.ui")

CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
PASSWORD = "bench-password-123"
ROLES = ("annotator", "reviewer", "admin")
DWELL_MS = 3000  # how long the simulated reviewer looks at a sample before pressing the key


def _progress(message: str) -> None:
    sys.stderr.write(f"[bench ui] {message}\n")
    sys.stderr.flush()


def run(tmp: Path, *, width: int, frames: int, repeats: int, brush_events: int, chromium: str,
        scripted: int = 3) -> dict[str, Any]:
    # `frames` samples as before (all but one reviewed), plus the scripted annotator's (3 runs of `scripted`,
    # and one for the work-loss checks), left in the annotation queue after them.
    capture = _synthesise(tmp / "capture", width, frames + 3 * scripted + 1)
    settings = Settings(data_dir=tmp / "data", environment="test", secret_key=uuid.uuid4().hex * 2)
    _prepare_database(settings, capture)
    _share_hand_model(settings.data_dir)
    _progress("starting the API process")
    with start_stack(settings, start_worker=False) as stack:
        base = stack.base_url
        tokens = {role: _token(base, role) for role in ROLES}
        reviewable = frames - 1  # one sample stays in the annotation queue for the brush test
        _progress(f"annotating and fitting {reviewable} samples from the ground truth (as a worker would)")
        _into_review(base, tokens, settings, capture, reviewable)
        from playwright.sync_api import sync_playwright  # deferred: a dev dependency, needed only here

        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            try:
                version = browser.version
                interactive, interactive_first = _interactive(browser, base, tokens, repeats)
                half = reviewable // 2
                next_sample = _next_sample(browser, base, tokens["reviewer"], half, with_3d=False, warm_up=True)
                next_3d = _next_sample(browser, base, tokens["reviewer"], reviewable - half, with_3d=True,
                                       warm_up=False)
                brush = _brush(browser, base, tokens["annotator"], brush_events)
                truth = _truth_by_frame(capture)
                losses = _work_loss(browser, base, tokens["annotator"], settings, truth)
                frame_of = _frames_of(settings)
                by_triangulation = _scripted_annotator(browser, base, tokens["annotator"], truth, scripted, "T",
                                                       frame_of)
                by_network = _scripted_annotator(browser, base, tokens["annotator"], truth, scripted, "M", frame_of)
                occlusion = _scripted_occlusion(browser, base, tokens["annotator"], truth, scripted, frame_of)
            finally:
                browser.close()
    worst_page = max(interactive, key=lambda p: interactive[p])
    return {
        "interactive_ms": interactive[worst_page],
        "interactive_ms_by_page": interactive,
        "interactive_slowest_page": worst_page,
        "interactive_first_after_start_ms": interactive_first,
        "next_sample_ms": next_sample["median_ms"],
        "next_sample_max_ms": next_sample["max_ms"],
        "next_sample_decisions": next_sample["n"],
        "next_sample_first_ms": next_sample["first_ms"],
        "next_sample_with_3d_view_ms": next_3d["median_ms"],
        "next_sample_with_3d_view_max_ms": next_3d["max_ms"],
        "decision_server_with_3d_view_ms": next_3d["decided_median_ms"],
        "decision_server_ms": next_sample["decided_median_ms"],
        "keys_per_decision": next_sample["keys_per_decision"],
        "brush_event_ms": brush["mean_ms"],
        "brush_event_p95_ms": brush["p95_ms"],
        "brush_event_max_ms": brush["max_ms"],
        "brush_image_px": brush["image_px"],
        "brush_pixels_painted": brush["painted"],
        "scripted_from_triangulation": by_triangulation,
        "scripted_from_network_proposals": by_network,
        "clicks_per_sample_T": by_triangulation["clicks_per_sample"],
        "clicks_per_sample_M": by_network["clicks_per_sample"],
        "seconds_per_sample_T": by_triangulation["seconds_per_sample"],
        "seconds_per_sample_M": by_network["seconds_per_sample"],
        "scripted_occlusion_from_proposals": occlusion,
        "clicks_per_sample_O": occlusion["clicks_per_sample"],
        "seconds_per_sample_O": occlusion["seconds_per_sample"],
        "occlusion_actions_per_occluded_point": occlusion["occlusion_actions_per_occluded_point"],
        "activity_logs_posted": ACTIVITY["posted"],
        "activity_logs_rejected": ACTIVITY["rejected"],
        "activity_events_rejected": ACTIVITY["events_rejected"],
        "reload_clicks_lost": losses["reload_clicks_lost"],
        "back_clicks_lost": losses["back_clicks_lost"],
        "lapsed_lease_clicks_lost": losses["lapsed_lease_clicks_lost"],
        "restore_ms": losses["restore_ms"],
        "targets": {"interactive_ms": 1000, "next_sample_ms": 200, "brush_event_ms": 16, "reload_clicks_lost": 0,
                    "back_clicks_lost": 0, "lapsed_lease_clicks_lost": 0, "activity_events_rejected": 0,
                    "occlusion_actions_per_occluded_point": 1},
        "chromium_version": version,
    }


# --- data ----------------------------------------------------------------------------------------------------


def _synthesise(out: Path, width: int, frames: int) -> Path:
    _progress(f"synthesising {frames} frames at {width} px")
    t0 = time.perf_counter()
    generate_capture(out, SynthConfig(num_sequences=1, frames_per_sequence=frames, seed=7, width_px=width), workers=1,
                     force=True)
    _progress(f"capture ready in {time.perf_counter() - t0:.0f} s")
    return out


def _prepare_database(settings, capture: Path) -> None:
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    upgrade(settings.resolved_database_url)
    engine = create_engine_from_url(settings.resolved_database_url)
    try:
        with make_session_factory(engine).begin() as session:
            import_capture(session, LocalDiskStorage(settings.storage_dir), capture, project_name="bench")
            for role in ROLES:
                create_user(session, f"{role}@bench.local", PASSWORD, Role(role), role)
    finally:
        engine.dispose()


def _share_hand_model(data_dir: Path) -> None:
    """The generated built-in hand of this machine's cache, so the fresh data folder does not regenerate it
    (a deployment's workers have made it long before a reviewer opens a fit)."""
    build_builtin_hand("right")  # makes sure this process's cache holds it
    target = data_dir / "cache"
    target.mkdir(parents=True, exist_ok=True)
    for path in cache.cache_dir().glob("builtin_hand_*.npz"):
        shutil.copyfile(path, target / path.name)


def _token(base: str, role: str) -> str:
    response = httpx.post(f"{base}/api/auth/token", data={"username": f"{role}@bench.local", "password": PASSWORD},
                          timeout=30)
    response.raise_for_status()
    return response.json()["access_token"]


def _into_review(base: str, tokens: dict[str, str], settings, capture: Path, count: int) -> None:
    """Submit the true clicks of `count` samples through the API, then record fits with the true
    parameters in the database (the worker's part), which sends them to review."""
    frames = read_capture(capture, check_images=False).sequences[0].frames
    engine = create_engine_from_url(settings.resolved_database_url)
    factory = make_session_factory(engine)
    headers = {"Authorization": f"Bearer {tokens['annotator']}"}
    with httpx.Client(base_url=base, headers=headers, timeout=60) as http:
        for _ in range(count):
            task = http.post("/api/annotate/next").json()
            gt = load_ground_truth(frames[task["frame_index"]])
            names = list(gt.camera_names)
            clicks = []
            for view in task["views"]:
                for k in task["keypoints_to_click"]:
                    x, y = (float(v) for v in gt.keypoints_2d[names.index(view["camera"]), k])
                    inside = -0.5 <= x <= view["width"] - 0.5 and -0.5 <= y <= view["height"] - 0.5
                    clicks.append({"view_id": view["id"], "keypoint": k, "x": x, "y": y, "visibility": "visible"}
                                  if inside else {"view_id": view["id"], "keypoint": k, "visibility": "not_annotated"})
            body = {"submission_id": uuid.uuid4().hex, "lease_token": task["lease_token"], "time_spent_s": 10.0,
                    "clicks": clicks}
            submitted = http.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=body)
            submitted.raise_for_status()
            params = gt.params.to_theta()
            with factory.begin() as session:
                records.record_fit(session, task["sample_id"], params=params.tolist(),
                                   keypoints_m=gt.keypoints_3d.tolist(),
                                   view_ious={v["id"]: 0.9 for v in task["views"]}, diagnostics={},
                                   inputs={"submission_ids": [submitted.json()["id"]]},
                                   model_file="handloop-builtin v1", thresholds=HeuristicThresholds())
    engine.dispose()


# --- browser measurements ------------------------------------------------------------------------------------


# Activity logs the pages post (POST /api/activity), over the whole run: how many, how many the API refused and
# the actions those held (each refused log loses all its actions).
ACTIVITY = {"posted": 0, "rejected": 0, "events_rejected": 0, "errors": []}


def _count_activity(response) -> None:
    request = response.request
    if request.method != "POST" or not request.url.endswith("/api/activity"):
        return
    ACTIVITY["posted"] += 1
    if response.status >= 400:
        ACTIVITY["rejected"] += 1
        try:
            ACTIVITY["events_rejected"] += len((request.post_data_json or {}).get("actions") or [])
            ACTIVITY["errors"].append(response.text()[:300])
        except Exception as exc:  # a body that cannot be read still counts as refused
            ACTIVITY["errors"].append(f"unreadable: {exc}")
        _progress(f"activity log refused ({response.status}): {ACTIVITY['errors'][-1]}")


def _context(browser, token: str):
    context = browser.new_context(viewport={"width": 1600, "height": 900})
    context.add_init_script(f"localStorage.setItem('handloop.token', {token!r});")
    context.on("response", _count_activity)
    return context


def _load(browser, base: str, token: str, name: str) -> float:
    """One first visit of a page in a new browser context (empty cache): ms from navigation start until
    the page is interactive (its `data-ready` mark)."""
    context = _context(browser, token)
    page = context.new_page()
    page.goto(f"{base}/#/{name}")
    page.wait_for_selector(f"body[data-ready={name}]", state="attached", timeout=60_000)
    ms = page.evaluate(f"() => window.__handloop.marks[{name!r}]")
    if name == "annotate":
        shown = page.evaluate("() => window.__handloop.page.metrics.shown[0]")
        _progress(f"  annotate: task data and images {shown['load_ms']:.0f} ms, drawing {shown['show_ms']:.0f} ms")
    if name != "admin":  # hand the leases back so the next load sees the same queues
        page.evaluate("() => window.__handloop.page.releaseAll()")
    context.close()
    return ms


def _interactive(browser, base: str, tokens: dict[str, str], repeats: int) -> tuple[dict[str, float], dict]:
    """Per page: the first load after the server started (it pays the server's one-off imports), then the
    median of `repeats` loads with an empty browser cache on the warm server."""
    pages = {"annotate": "annotator", "review": "reviewer", "admin": "admin"}
    out, first = {}, {}
    for name, role in pages.items():
        first[name] = round(_load(browser, base, tokens[role], name), 1)
        runs = [_load(browser, base, tokens[role], name) for _ in range(repeats)]
        out[name] = round(statistics.median(runs), 1)
        _progress(f"{name} page interactive: {out[name]} ms (runs {[round(r) for r in runs]}; first after the "
                  f"server started {first[name]:.0f} ms)")
    return out, first


def _next_sample(browser, base: str, token: str, decisions: int, *, with_3d: bool, warm_up: bool,
                 dwell_ms: int = DWELL_MS) -> dict[str, Any]:
    """Accept with one key press after looking at each sample for `dwell_ms` (the paper's reviewers take
    about 5 s per sample); the page measures key press -> next sample painted. With
    `warm_up` the first decision, which pays the server's one-off imports, is reported apart."""
    context = _context(browser, token)
    page = context.new_page()
    page.goto(f"{base}/#/review")
    page.wait_for_selector("body[data-ready=review]", state="attached", timeout=60_000)
    if page.evaluate("() => window.__handloop.page.show3d") != with_3d:
        page.keyboard.press("v")  # open or close the 3D view
    presses = 0
    for i in range(decisions):
        if i < decisions - 1:  # the last sample of the queue has no next to prefetch
            page.wait_for_function("() => window.__handloop.page.prepared !== null", timeout=60_000)
        page.wait_for_timeout(dwell_ms)
        before = page.evaluate("() => window.__handloop.page.metrics.decisions.length")
        page.keyboard.press("a")
        presses += 1
        page.wait_for_function(f"() => window.__handloop.page.metrics.decisions.length > {before}", timeout=60_000)
    metrics = page.evaluate("() => window.__handloop.page.metrics.decisions")
    context.close()
    first = metrics[0]["next_shown_ms"] if warm_up else None
    warm = [m for m in (metrics[1:] if warm_up else metrics) if m["prefetched"]]
    shown = [m["next_shown_ms"] for m in warm]
    _progress(f"next sample after a decision ({'with' if with_3d else 'without'} the 3D view): "
              f"{[round(v) for v in shown]} ms" + (f" (first after start {first:.0f} ms)" if warm_up else ""))
    return {"median_ms": round(statistics.median(shown), 1), "max_ms": round(max(shown), 1), "n": len(shown),
            "first_ms": None if first is None else round(first, 1),
            "decided_median_ms": round(statistics.median(m["decided_ms"] for m in warm), 1),
            "keys_per_decision": presses / len(metrics)}


BRUSH_SCRIPT = """async (n) => {
  const page = window.__handloop.page;
  const index = page.views.findIndex((v) => v.width === 1280 && v.height === 1024);
  page.selectView(index >= 0 ? index : 0);
  page.tool = 'brush';
  page.setMode('mask');
  page.setRadius(24);
  page.renderNow(true);
  const canvas = page.canvas, r = canvas.getBoundingClientRect();
  const view = page.view;
  const at = (i) => {
    const t = i / n, u = view.width * (0.2 + 0.6 * t), v = view.height * (0.5 + 0.3 * Math.sin(6.283 * 3 * t));
    const [x, y] = page.vp.toScreen(u, v);
    return {clientX: r.left + x, clientY: r.top + y, pointerId: 7, bubbles: true, button: 0, buttons: 1};
  };
  const before = page.ensureMask(view).count();
  canvas.dispatchEvent(new PointerEvent('pointerdown', at(0)));
  const times = [];
  for (let i = 1; i <= n; i++) {
    const t0 = performance.now();
    canvas.dispatchEvent(new PointerEvent('pointermove', at(i)));
    page.renderNow();
    times.push(performance.now() - t0);
  }
  canvas.dispatchEvent(new PointerEvent('pointerup', at(n)));
  return {times, width: view.width, height: view.height, painted: view.mask.count() - before};
}"""


def _brush(browser, base: str, token: str, events: int) -> dict[str, Any]:
    context = _context(browser, token)
    page = context.new_page()
    page.goto(f"{base}/#/annotate")
    page.wait_for_selector("body[data-ready=annotate]", state="attached", timeout=60_000)
    page.evaluate(BRUSH_SCRIPT, 20)  # warm-up (JIT, first overlay upload)
    page.keyboard.press("Control+z")
    out = page.evaluate(BRUSH_SCRIPT, events)
    # The strokes were saved as a draft: thrown away (the user's say) so the next runs start clean.
    page.evaluate("""async () => { const p = window.__handloop.page; await p.drafts.settle(); p.drafts.forget();
      await p.api.fetch('DELETE', `/api/annotate/samples/${p.task.sample_id}/draft`); await p.releaseAll(); }""")
    context.close()
    times = sorted(out["times"])
    mean = statistics.fmean(times)
    p95 = times[min(len(times) - 1, int(0.95 * len(times)))]
    _progress(f"brush on {out['width']}x{out['height']}: mean {mean:.2f} ms, p95 {p95:.2f} ms per event")
    return {"mean_ms": round(mean, 3), "p95_ms": round(p95, 3), "max_ms": round(times[-1], 3),
            "image_px": [out["width"], out["height"]], "painted": out["painted"]}


# --- annotation from proposals, and work that must never be lost ---------------------------------------------

SCREEN_OF = """([u, v]) => { const p = window.__handloop.page; const r = p.canvas.getBoundingClientRect();
  const s = p.vp.toScreen(u, v); return [r.left + s[0], r.top + s[1]]; }"""
TASK = """() => { const p = window.__handloop.page; return {sample_id: p.task.sample_id,
  frame_index: p.task.frame_index,
  views: p.views.map((v) => ({id: v.id, camera: v.camera, width: v.width, height: v.height}))}; }"""
SET = """() => { const p = window.__handloop.page; const out = [];
  for (const [view, m] of p.annotation.clicks) for (const [k, c] of m) out.push([view, k, c.x, c.y, c.from || null]);
  return out; }"""
SPARSE = (0, 4, 8, 12, 16, 20)
CORRECT_PX = 4.0  # an accepted point farther than this from the truth is corrected by hand
NOISE_PX = 3.0


def _truth_by_frame(capture: Path) -> dict[int, Any]:
    frames = read_capture(capture, check_images=False).sequences[0].frames
    return {i: load_ground_truth(f) for i, f in enumerate(frames)}


def _true_uv(truth: dict[int, Any], task: dict[str, Any], view_index: int, keypoint: int) -> list[float] | None:
    gt = truth[task["frame_index"]]
    view = task["views"][view_index]
    x, y = (float(v) for v in gt.keypoints_2d[list(gt.camera_names).index(view["camera"]), keypoint])
    return [x, y] if -0.5 <= x <= view["width"] - 0.5 and -0.5 <= y <= view["height"] - 0.5 else None


def _annotate_page(browser, base: str, token: str, route=None):
    context = _context(browser, token)
    page = context.new_page()
    if route is not None:
        page.route("**/proposals", route)
    page.goto(f"{base}/#/annotate")
    page.wait_for_selector("body[data-ready=annotate]", state="attached", timeout=60_000)
    return context, page


def _click(page, view_index: int, keypoint: int, uv: list[float]) -> None:
    if page.evaluate("() => window.__handloop.page.viewIndex") != view_index:
        page.click(f".thumb >> nth={view_index}")
    page.keyboard.press(str(SPARSE.index(keypoint) + 1))
    page.mouse.click(*page.evaluate(SCREEN_OF, uv))


def _scripted_annotator(browser, base: str, token: str, truth: dict[int, Any], samples: int, source: str,
                        frame_of: dict[int, int]) -> dict[str, Any]:
    """Annotate `samples` samples from proposals ("T": two views by hand, Enter in the rest; "M": Enter in
    every view on a network's proposals), correcting every accepted point more than CORRECT_PX off.
    Counts pointer clicks (placements and thumbnail clicks) and key presses; wall seconds per sample."""
    rng = np.random.default_rng(11)

    def network(route) -> None:
        # Proposals are fetched ahead (prefetch): the frame is that of the sample in the URL.
        response = route.fetch()
        body = response.json()
        gt = truth[frame_of[int(route.request.url.rsplit("/samples/", 1)[1].split("/")[0])]]
        names = list(gt.camera_names)
        views = {}
        for camera in body["cameras"]:
            uv = gt.keypoints_2d[names.index(camera["camera"])] + rng.normal(0, NOISE_PX, (21, 2))
            views[str(camera["view_id"])] = uv.round(2).tolist()
        conf = np.where(rng.random(21) < 0.2, 0.45, 0.9).tolist()
        body["sources"].append({"kind": "mvnet", "label": "MVNet-like (bench)", "confidences": conf, "views": views})
        route.fulfill(response=response, body=json.dumps(body))

    context, page = _annotate_page(browser, base, token, network if source == "M" else None)
    clicks = keys = 0
    seconds = []
    for _ in range(samples):
        task = page.evaluate(TASK)
        t0 = time.perf_counter()
        n_views = len(task["views"])
        for v in range(n_views):
            if page.evaluate("() => window.__handloop.page.viewIndex") != v:
                page.click(f".thumb >> nth={v}")
                clicks += 1
            if source == "T" and v < 2:
                for k in SPARSE:
                    uv = _true_uv(truth, task, v, k)
                    if uv is not None:
                        _click(page, v, k, uv)
                        clicks, keys = clicks + 1, keys + 1
                continue
            page.keyboard.press("Enter")
            keys += 1
            # Look at each keypoint: a wrong or missing one is placed by hand.
            got = {(view, k): (x, y) for view, k, x, y, _ in page.evaluate(SET) if view == task["views"][v]["id"]}
            for k in SPARSE:
                uv = _true_uv(truth, task, v, k)
                have = got.get((task["views"][v]["id"], k))
                if uv is None or (have is not None and have[0] is not None
                                  and np.hypot(have[0] - uv[0], have[1] - uv[1]) <= CORRECT_PX):
                    continue
                if have is not None:
                    page.keyboard.press(str(SPARSE.index(k) + 1))
                    page.keyboard.press("Delete")
                    keys += 2
                _click(page, v, k, uv)
                clicks, keys = clicks + 1, keys + 1
        keys += _submit(page, task["sample_id"])
        seconds.append(time.perf_counter() - t0)
    context.close()
    out = {"samples": samples, "clicks_per_sample": round(clicks / samples, 2),
           "keys_per_sample": round(keys / samples, 2), "seconds_per_sample": round(statistics.fmean(seconds), 2),
           "all_clicked_would_be": 6 * n_views}
    _progress(f"scripted annotator from {'triangulation' if source == 'T' else 'network proposals'}: "
              f"{out['clicks_per_sample']} clicks, {out['keys_per_sample']} keys, {out['seconds_per_sample']} s per "
              f"sample (all clicked by hand: {6 * n_views} clicks)")
    return out


VISIBILITY = """() => { const p = window.__handloop.page; const out = [];
  for (const [view, m] of p.annotation.clicks) for (const [k, c] of m) out.push([view, k, c.x, c.y, c.visibility]);
  return out; }"""


def _submit(page, sample_id: int) -> int:
    """Ctrl+Enter, and once more where the page asks first (points left unset): the keys it took, once the page
    has moved on from `sample_id`."""
    gone = (f"document.body.dataset.sample !== '{sample_id}' || "
            "document.body.dataset.ready === 'annotate-empty'")
    page.keyboard.press("Control+Enter")
    page.wait_for_function(f"() => {gone} || !!document.querySelector('.ask .confirm-submit')", timeout=60_000)
    keys = 1
    if page.evaluate(f"() => !({gone})"):
        page.keyboard.press("Control+Enter")
        keys += 1
        page.wait_for_function(f"() => {gone}", timeout=60_000)
    return keys


def _drag(page, view_index: int, start: Any, end: Any) -> None:
    if page.evaluate("() => window.__handloop.page.viewIndex") != view_index:
        page.click(f".thumb >> nth={view_index}")
    page.mouse.move(*page.evaluate(SCREEN_OF, [float(start[0]), float(start[1])]))
    page.mouse.down()
    page.mouse.move(*page.evaluate(SCREEN_OF, [float(end[0]), float(end[1])]), steps=4)
    page.mouse.up()


def _scripted_occlusion(browser, base: str, token: str, truth: dict[int, Any], samples: int,
                        frame_of: dict[int, int]) -> dict[str, Any]:
    """Annotate `samples` samples marking occlusion from proposals (module docstring, "O"): Enter per view, then
    drag each point more than CORRECT_PX off into place (a drag keeps its visibility), place a missing one by
    hand, then flip (digit, O) each keypoint whose visibility differs from the truth. Counts clicks (drags
    included), keys, and the keys spent on occlusion (the flips) per truly occluded keypoint in the image."""
    rng = np.random.default_rng(13)
    arrays = load_arrays("handloop-builtin v1", None, "right")

    def proposals(route) -> None:
        response = route.fetch()
        body = response.json()
        gt = truth[frame_of[int(route.request.url.rsplit("/samples/", 1)[1].split("/")[0])]]
        names = list(gt.camera_names)
        views = {}
        cameras = []
        for camera in body["cameras"]:
            uv = gt.keypoints_2d[names.index(camera["camera"])] + rng.normal(0, NOISE_PX, (21, 2))
            views[str(camera["view_id"])] = uv.round(2).tolist()
            cameras.append(ViewCamera(camera["camera"], camera["width"], camera["height"],
                                      *(np.asarray(camera[k], dtype=np.float64) for k in ("K", "dist", "R", "t")),
                                      view_id=camera["view_id"]))
        hidden = mesh_hidden(posed_mesh(arrays, gt.params), gt.keypoints_3d, cameras)
        fit = {"kind": "fit", "label": "fit (bench: the true hand)", "confidences": None, "views": {
            str(c.view_id): gt.keypoints_2d[names.index(c.name)].round(2).tolist() for c in cameras}, "hidden": hidden}
        body["sources"] = [{"kind": "mvnet", "label": "MVNet-like (bench)", "confidences": [0.9] * 21,
                            "views": views}, fit]
        route.fulfill(response=response, body=json.dumps(body))

    context, page = _annotate_page(browser, base, token, proposals)
    clicks = keys = occlusion_keys = occluded = left_wrong = 0
    seconds = []
    for _ in range(samples):
        task = page.evaluate(TASK)
        gt = truth[task["frame_index"]]
        names = list(gt.camera_names)
        t0 = time.perf_counter()
        for v, view in enumerate(task["views"]):
            if page.evaluate("() => window.__handloop.page.viewIndex") != v:
                page.click(f".thumb >> nth={v}")
                clicks += 1
            page.keyboard.press("Enter")
            keys += 1
            got = {k: (x, y, vis) for view_id, k, x, y, vis in page.evaluate(VISIBILITY) if view_id == view["id"]}
            for k in SPARSE:
                uv = _true_uv(truth, task, v, k)
                if uv is None:
                    continue
                hidden = not gt.visibility[names.index(view["camera"]), k]
                occluded += hidden
                want = "occluded" if hidden else "visible"
                have = got.get(k)
                if have is None or have[0] is None:  # no proposal: placed by hand
                    _click(page, v, k, uv)
                    clicks, keys = clicks + 1, keys + 1
                    have = (*uv, "visible")
                elif np.hypot(have[0] - uv[0], have[1] - uv[1]) > CORRECT_PX:  # dragged into place (keeps O)
                    _drag(page, v, have[:2], uv)
                    clicks += 1
                if have[2] != want:
                    if page.evaluate("() => window.__handloop.page.viewIndex") != v:  # a click moved the page on
                        page.click(f".thumb >> nth={v}")
                        clicks += 1
                    page.keyboard.press(str(SPARSE.index(k) + 1))
                    page.keyboard.press("o")
                    keys, occlusion_keys = keys + 2, occlusion_keys + 2
        wrong = [(view_id, k) for view_id, k, _, _, vis in page.evaluate(VISIBILITY)
                 for v, view in enumerate(task["views"]) if view["id"] == view_id and _true_uv(truth, task, v, k)
                 and vis != ("visible" if gt.visibility[names.index(view["camera"]), k] else "occluded")]
        left_wrong += len(wrong)
        keys += _submit(page, task["sample_id"])
        seconds.append(time.perf_counter() - t0)
    context.close()
    out = {"samples": samples, "clicks_per_sample": round(clicks / samples, 2),
           "keys_per_sample": round(keys / samples, 2), "seconds_per_sample": round(statistics.fmean(seconds), 2),
           "occluded_keypoints": occluded, "occlusion_keys": occlusion_keys,
           "occlusion_actions_per_occluded_point": round(occlusion_keys / occluded, 3) if occluded else None,
           "without_mesh_flags_would_be": 2.0, "keypoints_left_with_wrong_visibility": left_wrong}
    _progress(f"scripted annotator marking occlusion: {out['clicks_per_sample']} clicks, {out['keys_per_sample']} "
              f"keys, {out['seconds_per_sample']} s per sample; {occlusion_keys} keys for {occluded} occluded "
              f"keypoints ({out['occlusion_actions_per_occluded_point']} each; flipping each by hand: 2)")
    return out


def _frames_of(settings) -> dict[int, int]:
    """sample id -> frame index (the capture has one sequence)."""
    engine = create_engine_from_url(settings.resolved_database_url)
    with make_session_factory(engine)() as session:
        rows = session.execute(text("SELECT id, frame_index FROM samples")).all()
    engine.dispose()
    return {int(i): int(f) for i, f in rows}


def _work_loss(browser, base: str, token: str, settings, truth: dict[int, Any]) -> dict[str, Any]:
    """Clicks lost by a reload, by the Back button and by a lapsed lease on a free sample (each should be 0),
    and the reload's time to the draft restored."""
    context, page = _annotate_page(browser, base, token)
    task = page.evaluate(TASK)
    placed = 0
    for k in SPARSE:
        uv = _true_uv(truth, task, 0, k)
        if uv is not None:
            _click(page, 0, k, uv)
            placed += 1
    page.wait_for_selector("body[data-draft-state=saved]", state="attached", timeout=60_000)
    before = sorted(map(tuple, page.evaluate(SET)))
    page.reload()
    page.wait_for_selector("body[data-ready=annotate]", state="attached", timeout=60_000)
    restore_ms = page.evaluate("() => window.__handloop.marks.draftRestored ?? null")
    reload_lost = len(set(before) - set(map(tuple, page.evaluate(SET))))
    _click(page, 1, 0, _true_uv(truth, task, 1, 0) or [10.0, 10.0])
    before = sorted(map(tuple, page.evaluate(SET)))
    # The Back button within the app, at once, with the last click not yet saved: an entry pushed after this
    # page, then Back to it (hashchange: the page is unmounted and mounted again, as after any Back).
    page.evaluate("() => history.pushState(null, '', '#/elsewhere')")
    page.go_back()
    page.wait_for_function("() => window.__handloop.page && window.__handloop.page.task && "
                           "document.body.dataset.draft !== undefined && document.body.dataset.ready === 'annotate'",
                           timeout=60_000)
    back_lost = len(set(before) - set(map(tuple, page.evaluate(SET))))
    engine = create_engine_from_url(settings.resolved_database_url)
    with make_session_factory(engine).begin() as session:
        session.execute(text("UPDATE samples SET lease_expires_at = :t WHERE id = :i"),
                        {"t": utcnow() - timedelta(seconds=5), "i": task["sample_id"]})
    engine.dispose()
    _click(page, 2, 0, _true_uv(truth, task, 2, 0) or [10.0, 10.0])  # saved under a re-taken lease
    page.wait_for_function("() => document.body.dataset.draftState === 'saved'", timeout=60_000)
    before = sorted(map(tuple, page.evaluate(SET)))
    _submit(page, task["sample_id"])
    engine = create_engine_from_url(settings.resolved_database_url)
    with make_session_factory(engine)() as session:
        stored = session.execute(text("SELECT count(*) FROM clicks WHERE sample_id = :s AND visibility != "
                                      "'not_annotated'"), {"s": task["sample_id"]}).scalar_one()
    engine.dispose()
    lapsed_lost = len(before) - stored
    page.evaluate("() => window.__handloop.page.releaseAll()")
    context.close()
    _progress(f"work lost: reload {reload_lost}, Back {back_lost}, lapsed lease {lapsed_lost} clicks; draft restored "
              f"{restore_ms:.0f} ms after the reload's navigation start" if restore_ms is not None else
              "draft not restored after the reload")
    return {"reload_clicks_lost": reload_lost, "back_clicks_lost": back_lost, "lapsed_lease_clicks_lost": lapsed_lost,
            "restore_ms": None if restore_ms is None else round(restore_ms, 1), "clicks_before_reload": placed}
