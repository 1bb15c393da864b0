"""A real browser for the UI tests: Debian's Chromium, headless, driven by Playwright's Python package
(never `playwright install`: scripts/test.sh installs the `chromium` package). Without Chromium the
browser tests are skipped, or fail when CI is set. Screenshots go to test-output/browser/."""

from __future__ import annotations

import os
import shutil
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from tests.support.requirements import missing

REPO = Path(__file__).resolve().parents[2]
CHROMIUM = os.environ.get("HANDLOOP_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
SHOTS = REPO / "test-output" / "browser"


def _chromium_or_skip() -> str:
    if not (Path(CHROMIUM).exists() or shutil.which(CHROMIUM)):
        message = f"Chromium is not installed at {CHROMIUM} (scripts/test.sh runs `apt-get install -y chromium`)"
        missing(message, needed_by="the browser tests")
    return CHROMIUM


# Per module, not per session: Playwright's sync API keeps its event loop marked running while it is open, so
# a test run after it in the same process (with pytest-xdist, any module) could not start a loop of its own
# (`bench api`'s client, `bench import --ui`'s own Playwright).
@pytest.fixture(scope="module")
def browser() -> Iterator:
    executable = _chromium_or_skip()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        instance = playwright.chromium.launch(executable_path=executable, args=CHROMIUM_ARGS)
        yield instance
        instance.close()


@dataclass
class Tab:
    """A page with its console errors collected (a test fails on any uncaught page error)."""

    page: object
    errors: list[str] = field(default_factory=list)

    def shot(self, name: str, timeout_ms: float = 30_000) -> Path:
        SHOTS.mkdir(parents=True, exist_ok=True)
        path = SHOTS / f"{name}.png"
        self.page.screenshot(path=str(path), timeout=timeout_ms)
        return path


@pytest.fixture
def tab(browser) -> Iterator:
    """tab(viewport=(w, h)) -> Tab, closed after the test."""
    contexts = []

    def make(width: int = 1600, height: int = 900) -> Tab:
        context = browser.new_context(viewport={"width": width, "height": height})
        contexts.append(context)
        page = context.new_page()
        t = Tab(page)
        page.on("pageerror", lambda e: t.errors.append(str(e)))
        return t

    yield make
    for context in contexts:
        context.close()


def sign_in(tab: Tab, base_url: str, email: str, password: str, expect: str) -> None:
    page = tab.page
    page.goto(base_url + "/")
    page.wait_for_selector("body[data-ready=login]", state="attached")
    page.fill("input[name=email]", email)
    page.fill("input[name=password]", password)
    page.click("button[type=submit]")
    page.wait_for_selector(f"body[data-ready={expect}]", state="attached", timeout=60_000)


# What the pages publish as data-* attributes (frontend/js/annotate.js publish(), annotate_drawing.js, review.js
# publish()): the tests read these, not the pages' fields. The annotate page's enlarged view: its canvas carries
# the zoom (data-scale, data-ox, data-oy); each thumbnail its view (data-view-id, data-loaded, data-k{keypoint}).
SCREEN_OF = """([u, v]) => { const c = document.querySelector('canvas.main-canvas');
  const r = c.getBoundingClientRect(); const s = Number(c.dataset.scale);
  return [r.left + (u + 0.5) * s + Number(c.dataset.ox), r.top + (v + 0.5) * s + Number(c.dataset.oy)]; }"""
IMAGE_OF = """([x, y]) => { const c = document.querySelector('canvas.main-canvas'); const s = Number(c.dataset.scale);
  return [(x - Number(c.dataset.ox)) / s - 0.5, (y - Number(c.dataset.oy)) / s - 0.5]; }"""
VIEWPORT = """() => { const d = document.querySelector('canvas.main-canvas').dataset;
  return [Number(d.scale), Number(d.ox), Number(d.oy)]; }"""
SCALE = "() => Number(document.querySelector('canvas.main-canvas').dataset.scale)"
STATUS = "([v, k]) => document.querySelectorAll('.thumbs .thumb')[v].dataset['k' + k]"
VIEW_IDS = "() => [...document.querySelectorAll('.thumbs .thumb')].map((t) => Number(t.dataset.viewId))"
SAMPLE = "() => document.body.dataset.sample === undefined ? null : Number(document.body.dataset.sample)"
VIEW_INDEX = "() => Number(document.body.dataset.viewIndex)"
KEYPOINT = "() => Number(document.body.dataset.keypoint)"
# The task on screen: {sample_id, sequence_id, frame_index, views: [{id, camera, width, height}]} (for ground_truth_of).
TASK = """() => { const d = document.body.dataset;
  return {sample_id: Number(d.sample), sequence_id: Number(d.sequenceId), frame_index: Number(d.frameIndex),
    views: [...document.querySelectorAll('.thumbs .thumb')].map((t) => ({id: Number(t.dataset.viewId),
      camera: t.dataset.camera, width: Number(t.dataset.width), height: Number(t.dataset.height)}))}; }"""
# The scale at which the view on screen shows whole (with the page's 8 px margin), screen px per image px.
WHOLE_SCALE = """() => { const r = document.querySelector('canvas.main-canvas').getBoundingClientRect();
  const v = document.querySelectorAll('.thumbs .thumb')[Number(document.body.dataset.viewIndex)].dataset;
  return Math.min((r.width - 16) / Number(v.width), (r.height - 16) / Number(v.height)); }"""
VIEW_AND_KEYPOINT = "() => [Number(document.body.dataset.viewIndex), Number(document.body.dataset.keypoint)]"
# The full-resolution height of the view on screen (its thumbnail's data-height), px.
VIEW_HEIGHT = """() => Number(document.querySelectorAll('.thumbs .thumb')[Number(document.body.dataset.viewIndex)]
  .dataset.height)"""


def wait_for_every_view(page) -> None:
    """The annotate page is ready once its first view has loaded; the others fill in after (by design, so the
    annotator starts sooner). A test that reads every view's image waits for them all here."""
    page.wait_for_function("() => { const t = [...document.querySelectorAll('.thumbs .thumb')];"
                           " return t.length > 0 && t.every((e) => e.dataset.loaded === 'yes'); }", timeout=60_000)


class _QuietHandler(SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:  # the test output is not the place for access logs
        pass


@pytest.fixture(scope="session")
def static_frontend() -> Iterator[str]:
    """The frontend directory over HTTP (ES modules need an origin), for the JS logic tests."""
    handler = partial(_QuietHandler, directory=str(REPO / "frontend"))
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()


def open_3d_view(page, *, loaded: bool = False) -> None:
    """The review page's 3D view opened (V where it starts closed: software WebGL, as in this headless browser),
    its iframe in the page; with loaded, its document loaded too."""
    if page.get_attribute("body", "data-show3d") != "yes":
        page.keyboard.press("v")
    page.wait_for_selector("iframe.viewer-frame")
    if loaded:
        page.wait_for_function("() => { const f = document.querySelector('iframe.viewer-frame');"
                               " return f && f.contentDocument && f.contentDocument.readyState === 'complete'; }",
                               timeout=60_000)


def submit_as_is(page) -> None:
    """Ctrl+Enter on the annotate page; where it asks first (points not set: issue 38), Ctrl+Enter again submits
    them as not annotated."""
    page.keyboard.press("Control+Enter")
    if page.evaluate("() => document.body.dataset.ask === 'submit'"):
        page.keyboard.press("Control+Enter")
