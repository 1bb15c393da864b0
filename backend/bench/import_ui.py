"""The annotate page's time to interactive on a real-sized imported capture (`handloop bench import`'s
browser step, issue 18): the project `bench import` just imported (8 views of 2048x1536), served by the
real API process (`backend.runtime.start_stack`, no worker), opened in Debian's headless Chromium through
Playwright as `handloop bench ui` does.

interactive_ms: navigation start -> the annotate page's `data-ready` mark (task drawn, keys bound), each a
first visit (empty cache) in a new browser context on a warm server; median of `repeats` after one
warm-up load (the server's one-off imports, reported apart). Measured twice: with the capture's working
width (the page gets working-width copies of the images, derived on the first request: the warm-up load
derives those of the first sample, the timed loads see them stored) and with the full-resolution images
(the project's working width cleared), so the working width's effect is a number. And the first visit
of a sample whose copies are not derived yet, on the warm server (`underived_interactive_ms`: the stored
copies removed before each load): what the first annotator of a sample waits when the page's prefetch of
the next sample has not derived them ahead.
"""

from __future__ import annotations

import shutil
import statistics
import sys
import uuid
from pathlib import Path
from typing import Any

import httpx
from sqlalchemy import update

from backend.db.session import create_engine_from_url, make_session_factory
from backend.models.capture import Project
from backend.models.enums import Role
from backend.runtime import start_stack
from backend.services.accounts.users import create_user
from backend.settings import Settings
from workers.capture.working import DERIVED_PREFIX

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
PASSWORD = "bench-password-123"
EMAIL = "annotator@bench.local"


def _progress(message: str) -> None:
    sys.stderr.write(f"[bench import] {message}\n")
    sys.stderr.flush()


def _set_working_width(url: str, project: str, width: int | None) -> None:


    engine = create_engine_from_url(url)
    try:
        with make_session_factory(engine).begin() as session:
            session.execute(update(Project).where(Project.name == project).values(working_width_px=width))
    finally:
        engine.dispose()


def _add_annotator(url: str) -> None:

    engine = create_engine_from_url(url)
    try:
        with make_session_factory(engine).begin() as session:
            create_user(session, EMAIL, PASSWORD, Role.annotator, "annotator")
    finally:
        engine.dispose()


def _load(browser, base: str, token: str) -> dict[str, float]:
    """One first visit of the annotate page in a new browser context: ms to interactive, and the page's own
    split (task data and images; drawing)."""
    context = browser.new_context(viewport={"width": 1600, "height": 900})
    context.add_init_script(f"localStorage.setItem('handloop.token', {token!r});")
    page = context.new_page()
    page.goto(f"{base}/#/annotate")
    page.wait_for_selector("body[data-ready=annotate]", state="attached", timeout=120_000)
    ms = float(page.evaluate("() => window.__handloop.marks['annotate']"))
    shown = page.evaluate("() => window.__handloop.page.metrics.shown[0]")
    view = page.evaluate("() => { const v = window.__handloop.page.views[0];"
                         " return [v.width, v.height, v.image.width, v.image.height]; }")
    page.evaluate("() => window.__handloop.page.releaseAll()")  # the next load sees the same queue
    context.close()
    return {"interactive_ms": ms, "load_ms": float(shown["load_ms"]), "show_ms": float(shown["show_ms"]),
            "view_px": view[:2], "image_px": view[2:]}


def _series(browser, base: str, token: str, repeats: int, label: str) -> dict[str, Any]:
    first = _load(browser, base, token)
    runs = [_load(browser, base, token) for _ in range(repeats)]
    out = {
        "interactive_ms": round(statistics.median(r["interactive_ms"] for r in runs), 1),
        "interactive_runs_ms": [round(r["interactive_ms"], 1) for r in runs],
        "interactive_first_ms": round(first["interactive_ms"], 1),
        "task_and_images_ms": round(statistics.median(r["load_ms"] for r in runs), 1),
        "drawing_ms": round(statistics.median(r["show_ms"] for r in runs), 1),
        "view_px": runs[0]["view_px"], "image_px": runs[0]["image_px"],
    }
    _progress(f"annotate page interactive, {label}: {out['interactive_ms']} ms (runs {out['interactive_runs_ms']}, "
              f"first {out['interactive_first_ms']} ms; images {out['image_px']} for views {out['view_px']})")
    return out


def measure(database_url: str, storage_dir: Path, project: str, *, working_width: int | None, repeats: int = 3,
            chromium: str = CHROMIUM) -> dict[str, Any]:
    """The annotate page's time to interactive on the imported `project`, at its working width and at full
    resolution. The database and storage are those the import wrote (its data folder's layout)."""
    from playwright.sync_api import sync_playwright  # deferred: a dev dependency, needed only with --ui


    data_dir = storage_dir.parent
    settings = Settings(data_dir=data_dir, database_url=database_url, environment="test",
                        secret_key=uuid.uuid4().hex * 2)
    _add_annotator(database_url)
    result: dict[str, Any] = {"repeats": repeats}
    _progress("starting the API process for the annotate page")
    with start_stack(settings, start_worker=False) as stack:
        base = stack.base_url
        response = httpx.post(f"{base}/api/auth/token", data={"username": EMAIL, "password": PASSWORD}, timeout=60)
        response.raise_for_status()
        token = response.json()["access_token"]
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            try:
                result["chromium_version"] = browser.version
                if working_width is not None:
                    result["at_working_width"] = _series(browser, base, token, repeats,
                                                         f"working width {working_width} px")
                    underived = []
                    for _ in range(repeats):
                        shutil.rmtree(storage_dir / DERIVED_PREFIX, ignore_errors=True)
                        underived.append(_load(browser, base, token)["interactive_ms"])
                    result["at_working_width"]["underived_interactive_ms"] = round(statistics.median(underived), 1)
                    result["at_working_width"]["underived_runs_ms"] = [round(v, 1) for v in underived]
                    _progress(f"annotate page interactive, copies not derived yet: {underived}")
                _set_working_width(database_url, project, None)
                result["at_full_resolution"] = _series(browser, base, token, repeats, "full resolution")
            finally:
                browser.close()
                _set_working_width(database_url, project, working_width)
    shown = result.get("at_working_width") or result["at_full_resolution"]
    result["interactive_ms"] = shown["interactive_ms"]
    return result
