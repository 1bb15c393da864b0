"""The UI's pure JavaScript modules, run in Chromium and checked against the Python references: the
camera model (cv2.projectPoints), triangulation, the mask codec (backend/services/captures/masks.py), brush
strokes, undo/redo, the viewport's pixel convention, proposals and the mesh outline."""

from __future__ import annotations

import numpy as np
import pytest

from backend.services.captures.masks import decode_rle, encode_rle
from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def js(browser, static_frontend):
    context = browser.new_context()
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(static_frontend + "/index.html")  # an origin for the module imports; the app itself is not used

    def run(body: str, arg=None):
        result = page.evaluate(f"async (arg) => {{ {body} }}", arg)
        assert not errors, errors
        return result

    yield run
    context.close()


def _cameras():
    return [{"view_id": i + 1, "width": c.width, "height": c.height, "K": c.K.tolist(), "dist": c.dist.tolist(),
             "R": c.R.tolist(), "t": c.t.tolist()} for i, c in enumerate(default_rig(640))]


def test_projection_matches_opencv_and_inverts(js):
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.15, 0.15, (40, 3))
    cams = default_rig(640)
    expected, _ = project_points(points, cams)  # (C, N, 2), tested against cv2.projectPoints
    got = js("""const g = await import('/js/geometry.js');
                return arg.cams.map((c) => arg.points.map((p) => g.projectPoint(p, c)));""",
             {"cams": _cameras(), "points": points.tolist()})
    np.testing.assert_allclose(np.array(got), expected, atol=1e-6)
    # Undistorting the projection gives back x/z, y/z.
    back = js("""const g = await import('/js/geometry.js');
                 return arg.cams.map((c) => arg.points.map((p) => g.undistortPixel(g.projectPoint(p, c), c)));""",
              {"cams": _cameras(), "points": points.tolist()})
    for c, cam in enumerate(cams):
        X = points @ cam.R.T + cam.t
        np.testing.assert_allclose(np.array(back[c]), X[:, :2] / X[:, 2:], atol=1e-9)


def test_triangulation_recovers_points_and_drops_an_outlier(js):
    cams = default_rig(640)
    point = np.array([0.03, -0.02, 0.05])
    pixels, _ = project_points(point[None], cams)
    obs = [{"cam": c, "pixel": pixels[i, 0].tolist()} for i, c in enumerate(_cameras())]
    exact = js("const g = await import('/js/geometry.js'); return g.triangulate(arg);", obs[:2])
    np.testing.assert_allclose(exact["point"], point, atol=1e-7)
    obs[3]["pixel"] = (pixels[3, 0] + [40.0, -25.0]).tolist()  # one view clicked on the wrong finger
    robust = js("const g = await import('/js/geometry.js'); return g.triangulate(arg);", obs)
    np.testing.assert_allclose(robust["point"], point, atol=1e-6)
    assert 4 not in robust["used"] and len(robust["used"]) == 7
    assert js("const g = await import('/js/geometry.js'); return g.triangulate(arg);", obs[:1]) is None


def test_mask_codec_matches_the_server(js):
    rng = np.random.default_rng(1)
    mask = rng.random((37, 53)) < 0.3
    mask[0, 0] = True  # starts with foreground: a zero-length first run
    rle = js("""const m = await import('/js/mask.js');
                const layer = new m.MaskLayer(arg.w, arg.h, Uint8Array.from(arg.bits));
                return layer.toRLE();""", {"w": 53, "h": 37, "bits": mask.ravel().astype(int).tolist()})
    assert rle == encode_rle(mask)
    np.testing.assert_array_equal(decode_rle(rle, 53, 37), mask)
    bits = js("""const m = await import('/js/mask.js');
                 return Array.from(m.MaskLayer.fromRLE(arg.rle, 53, 37).bits);""", {"rle": rle})
    np.testing.assert_array_equal(np.array(bits, bool).reshape(37, 53), mask)
    error = js("""const m = await import('/js/mask.js');
                  try { m.MaskLayer.fromRLE([5, 5], 53, 37); return null; } catch (e) { return e.message; }""")
    assert "covers 10 pixels" in error


def test_brush_stroke_paints_the_capsule_and_undo_restores_it(js):
    W, H, r = 80, 60, 6.5
    a, b = np.array([10.0, 12.0]), np.array([55.0, 40.0])
    yy, xx = np.mgrid[0:H, 0:W]
    p = np.stack([xx, yy], -1).astype(float)
    t = np.clip(((p - a) @ (b - a)) / ((b - a) @ (b - a)), 0, 1)
    expected = np.linalg.norm(p - (a + t[..., None] * (b - a)), axis=-1) <= r
    out = js("""const m = await import('/js/mask.js');
                const layer = new m.MaskLayer(arg.W, arg.H);
                const rec = new m.StrokeRecorder(layer);
                rec.add(layer.stroke(arg.a[0], arg.a[1], arg.b[0], arg.b[1], arg.r, 1));
                const painted = Array.from(layer.bits);
                const cmd = rec.finish(() => {});
                cmd.undo(); const undone = layer.count();
                cmd.redo(); const redone = Array.from(layer.bits);
                const erased = layer.stroke(arg.a[0], arg.a[1], arg.a[0], arg.a[1], 3, 0);
                return {painted, undone, redone, rect: cmd.rect, erased, left: layer.count()};""",
             {"W": W, "H": H, "a": a.tolist(), "b": b.tolist(), "r": r})
    np.testing.assert_array_equal(np.array(out["painted"], bool).reshape(H, W), expected)
    assert out["undone"] == 0 and out["redone"] == out["painted"]
    xs = np.nonzero(expected)[1]
    assert out["rect"]["x"] <= xs.min() and out["rect"]["x"] + out["rect"]["w"] > xs.max()
    assert out["left"] == expected.sum() - (np.hypot(xx - a[0], yy - a[1]) <= 3).sum()


def test_history_undo_redo(js):
    out = js("""const {History} = await import('/js/history.js');
                const h = new History(); const log = []; let v = 0;
                const set = (to) => { const from = v; v = to;
                                      h.record({undo: () => { v = from; }, redo: () => { v = to; }}); };
                set(1); set(2); set(3);
                h.undo(); log.push(v); h.undo(); log.push(v); h.redo(); log.push(v);
                set(9); log.push(h.canRedo); h.undo(); log.push(v);
                h.undo(); h.undo(); log.push(v, h.canUndo, h.undo());
                return log;""")
    assert out == [2, 1, 2, False, 2, 0, False, None]


def test_viewport_pixel_convention_and_zoom(js):
    out = js("""const {Viewport} = await import('/js/viewport.js');
                const vp = new Viewport().fit(100, 50, 400, 300, 0);
                const corner = vp.toScreen(-0.5, -0.5), centre = vp.toScreen(49.5, 24.5);
                const before = vp.toImage(123, 77); vp.zoomAt(2.5, 123, 77); const after = vp.toImage(123, 77);
                const round = vp.toImage(...vp.toScreen(12.25, 7.75));
                return {scale: vp.scale, corner, centre, before, after, round};""")
    assert out["corner"] == [0, 50] and out["centre"] == [200, 150]  # 4 px per pixel, letterboxed vertically
    np.testing.assert_allclose(out["before"], out["after"], atol=1e-9)
    np.testing.assert_allclose(out["round"], [12.25, 7.75], atol=1e-9)
    assert out["scale"] == 10


def test_proposals_prefer_triangulation_then_fit_then_confident_mvnet(js):
    cams = default_rig(640)
    cameras = _cameras()
    kp = np.zeros((21, 3))
    kp[[0, 4]] = [[0.0, 0.0, 0.0], [0.05, 0.02, 0.03]]
    pixels, _ = project_points(kp, cams)
    fit_views = {str(c["view_id"]): [[10.0 + k, 20.0] for k in range(21)] for c in cameras}
    mvnet_views = {str(c["view_id"]): [[30.0 + k, 40.0] for k in range(21)] for c in cameras}
    conf = [0.9] * 21
    conf[12] = 0.1
    out = js("""const a = await import('/js/annotation.js');
                const ann = new a.Annotation(arg.cameras.map((c) => c.view_id), [0, 4, 8, 12]);
                for (const v of [1, 2]) {
                  ann.set(v, 0, {x: arg.px[v - 1][0][0], y: arg.px[v - 1][0][1], visibility: 'visible'});
                }
                ann.set(1, 4, {x: arg.px[0][4][0], y: arg.px[0][4][1], visibility: 'occluded'});
                const cams = new Map(arg.cameras.map((c) => [c.view_id, c]));
                const sources = [{kind: 'fit', views: arg.fit, confidences: null},
                                 {kind: 'mvnet', views: arg.mvnet, confidences: arg.conf}];
                const p = a.proposals(ann, cams, sources);
                const only = a.proposals(ann, cams, [sources[1]]);
                return {v3: Object.fromEntries(p.get(3)), v1: Object.fromEntries(p.get(1)),
                        mv: Object.fromEntries(only.get(3)), clicks: ann.toClicks().length};""",
             {"cameras": cameras, "px": pixels.tolist(), "fit": fit_views, "mvnet": mvnet_views, "conf": conf})
    assert out["v3"]["0"]["source"] == "triangulated"
    np.testing.assert_allclose([out["v3"]["0"]["x"], out["v3"]["0"]["y"]], pixels[2, 0], atol=1e-6)
    assert out["v3"]["4"]["source"] == "fit"  # one view only: no triangulation yet
    assert "0" not in out["v1"] and "4" not in out["v1"]  # set keypoints get no proposal
    assert out["mv"]["8"]["source"] == "mvnet" and "12" not in out["mv"]  # confidence 0.1 is not offered
    assert out["clicks"] == 8 * 4


def test_epipolar_curves_pass_through_the_point_in_every_other_view(js):
    cams = default_rig(640)
    point = np.array([0.03, -0.02, 0.05])
    pixels, _ = project_points(point[None], cams)  # (C, 1, 2)
    curves = js("""const g = await import('/js/geometry.js');
                   return arg.cams.slice(1).map((c) => g.epipolarCurve(arg.uv, arg.cams[0], c, {steps: 4000}));""",
                {"cams": _cameras(), "uv": pixels[0, 0].tolist()})
    for c, curve in enumerate(curves, start=1):
        distance = np.nanmin(np.linalg.norm(np.asarray(curve, dtype=float) - pixels[c, 0], axis=1))
        assert distance < 0.5, (c, distance)  # sampled finely, the curve passes within half a pixel
    other = np.array([0.08, 0.05, -0.04])
    far, _ = project_points(other[None], cams)
    assert np.nanmin(np.linalg.norm(np.asarray(curves[0], dtype=float) - far[1, 0], axis=1)) > 2.0  # not on it


def test_proposals_carry_confidence_and_accepted_ones_never_triangulate(js):
    cams = default_rig(640)
    cameras = _cameras()
    kp = np.zeros((21, 3))
    pixels, _ = project_points(kp, cams)
    out = js("""const a = await import('/js/annotation.js');
                const ann = new a.Annotation(arg.cameras.map((c) => c.view_id), [0, 4]);
                const cams = new Map(arg.cameras.map((c) => [c.view_id, c]));
                const at = (v, dx = 0) => ({x: arg.px[v - 1][0][0] + dx, y: arg.px[v - 1][0][1],
                                             visibility: 'visible'});
                ann.set(1, 0, at(1));
                ann.set(2, 0, {...at(2), from: 'mvnet'});  // accepted, not clicked: no triangulation from it
                const one = a.proposals(ann, cams, []).get(3).get(0) || null;
                ann.set(2, 0, at(2));
                const exact = a.proposals(ann, cams, []).get(3).get(0);
                ann.set(2, 0, at(2, 0));
                ann.set(4, 0, at(4, 6));  // a 6 px slip in a third view: the worst error lowers the confidence
                const slipped = a.triangulateClicked(ann, cams, 0);
                const mv = a.proposals(new a.Annotation([1], [0, 4]), cams, [{kind: 'mvnet', views: {'1': arg.mv},
                  confidences: arg.conf}]).get(1);
                return {one, exact, slipped: slipped.confidence, mv: Object.fromEntries(mv),
                        flags: ann.toClicks().filter((c) => c.keypoint === 0 && c.x !== undefined)
                          .map((c) => c.from_proposal)};""",
             {"cameras": cameras, "px": pixels.tolist(), "mv": [[30.0 + k, 40.0] for k in range(21)],
              "conf": [0.45 if k == 4 else 0.9 for k in range(21)]})
    assert out["one"] is None
    assert out["exact"]["source"] == "triangulated" and out["exact"]["confidence"] > 0.99
    assert 0.0 < out["slipped"] < 0.9
    assert out["mv"]["0"]["confidence"] == 0.9 and out["mv"]["4"]["confidence"] == 0.45
    assert out["flags"] == [False, False, False]


def test_mesh_edges_and_contour(js):
    out = js("""const m = await import('/js/mesh.js');
                const cube = Int32Array.from([0,1,2, 0,2,3, 4,6,5, 4,7,6, 0,4,5, 0,5,1, 1,5,6, 1,6,2, 2,6,7, 2,7,3,
                                              3,7,4, 3,4,0]);
                const e = m.meshEdges(cube);
                const square = Int32Array.from([0, 1, 2, 0, 2, 3]);
                const s = m.meshEdges(square);
                const px = Float64Array.from([0, 0, 1, 0, 1, 1, 0, 1]);
                return {cubeEdges: e.edges.length / 2, open: Array.from(e.edgeFaces).filter((f) => f < 0).length,
                        squareContour: m.contourEdges(px, {faces: square, edgeFaces: s.edgeFaces}).length,
                        squareEdges: s.edges.length / 2};""")
    assert out == {"cubeEdges": 18, "open": 0, "squareContour": 4, "squareEdges": 5}


def test_markers_carry_a_light_and_a_dark_ring_on_skin_mask_and_background(js):
    # Along a ray out of a placed marker (r = 6 px): its colour, a white ring, then a dark ring, whatever is
    # under it: the grey wrist and the blue fingers stay visible on skin, the mask's tint and a dark background.
    rings = js("""const d = await import('/js/draw.js');
        const out = {};
        for (const [name, under] of Object.entries(arg.grounds)) for (const k of [0, 4, 8]) {
          const c = document.createElement('canvas'); c.width = 40; c.height = 40;
          const ctx = c.getContext('2d'); ctx.fillStyle = under; ctx.fillRect(0, 0, 40, 40);
          d.marker(ctx, 20, 20, k, { r: 6 });
          const px = ctx.getImageData(20, 20, 20, 1).data;  // the row to the right of the centre
          out[`${name}/${k}`] = Array.from({ length: 12 }, (_, i) => [px[4 * i], px[4 * i + 1], px[4 * i + 2]]);
        }
        return out;""", {"grounds": {"skin": "#d9a58a", "mask": "#7aa0d8", "dark": "#141414", "light": "#f2f2f2"}})
    for where, row in rings.items():
        lum = [0.2126 * r + 0.7152 * g + 0.0722 * b for r, g, b in row]
        light = max(range(4, 8), key=lambda i: lum[i])
        dark = min(range(light + 1, 10), key=lambda i: lum[i])
        assert lum[light] > 200 and lum[dark] < 70, (where, [round(v) for v in lum])


def test_the_annotate_clock_counts_no_idle_gap_and_the_review_clock_keeps_its_cap(js):
    out = js("""const {ActionTimer} = await import('/js/timing.js');
                let t = 0; const now = () => t;
                const work = new ActionTimer({dropIdle: true, now});
                t = 5000; work.input(); t = 12000; const a = work.mark('click');  // 12 s of work
                t = 12000 + 600000; const idle = [work.idle(), work.spentSeconds()];  // ten minutes away
                const b = work.mark('click');  // the gap adds nothing
                t += 20000; work.pause(); t += 20000; const c = work.mark('click');  // hidden tab: 20 s, then none
                const capped = new ActionTimer({now}); t += 600000; const d = capped.mark('decide');
                return {a: a.duration_ms, idle, b: b.duration_ms, c: c.duration_ms, spent: work.spentSeconds(),
                        d: d.duration_ms};""")
    assert out["a"] == 12000 and out["idle"] == [True, 12.0] and out["b"] == 0
    assert out["c"] == 20000 and out["spent"] == 32.0
    assert out["d"] == 30000  # the review page's rule, unchanged: a pause counts up to 30 s
