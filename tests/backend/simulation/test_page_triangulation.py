"""The simulated annotator's port of the annotate page's triangulated proposal (geometry.js, annotation.js):
the page's rules on a synthetic rig, and, where node is installed, the same numbers as the JavaScript."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from backend.simulation.annotator import offered_proposals
from backend.simulation.page_triangulation import (
    TRIANGULATION_ZERO_CONF_PX,
    project_point,
    triangulate_clicked,
    triangulated_proposal,
)
from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig

FRONTEND_JS = Path(__file__).resolve().parents[3] / "frontend" / "js"


def _cameras() -> list[dict]:
    """The proposals endpoint's `cameras` for the default rig at 640 px (ViewCamera.to_public's keys)."""
    return [{"view_id": i + 1, "camera": c.name, "width": c.width, "height": c.height, "K": c.K.tolist(),
             "dist": c.dist.tolist(), "R": c.R.tolist(), "t": c.t.tolist()} for i, c in enumerate(default_rig(640))]


def _pixels(point: np.ndarray) -> np.ndarray:
    pixels, _ = project_points(point[None], default_rig(640))
    return pixels[:, 0]  # (C, 2)


def test_projection_matches_opencv():
    point = np.array([0.03, -0.02, 0.05])
    for cam, expected in zip(_cameras(), _pixels(point), strict=True):
        np.testing.assert_allclose(project_point(point, cam), expected, atol=1e-6)


def test_two_hand_placed_views_are_needed_and_an_outlier_view_is_dropped():
    cams, point = _cameras(), np.array([0.03, -0.02, 0.05])
    px = _pixels(point)
    assert triangulate_clicked([(cams[0], px[0])]) is None  # one view: nothing offered
    assert triangulated_proposal([(cams[0], px[0])], cams[2]) is None
    exact = triangulate_clicked([(cams[0], px[0]), (cams[1], px[1])])
    np.testing.assert_allclose(exact.point, point, atol=1e-7)
    assert exact.confidence > 0.999 and exact.used == (1, 2)
    np.testing.assert_allclose(triangulated_proposal([(cams[0], px[0]), (cams[1], px[1])], cams[2]), px[2], atol=1e-5)
    # A fingertip clicked on the wrong finger in one of four views: dropped (over 12 px), the rest agree.
    wrong = px[3] + [40.0, -25.0]
    robust = triangulate_clicked([(cams[i], px[i]) for i in range(3)] + [(cams[3], wrong)])
    assert robust.used == (1, 2, 3) and robust.confidence > 0.999
    np.testing.assert_allclose(robust.point, point, atol=1e-6)


def test_confidence_falls_with_the_worst_error_and_two_views_keep_their_outlier():
    cams, point = _cameras(), np.array([0.0, 0.01, 0.02])
    px = _pixels(point)
    # Two views are never pruned: the disagreement shows as reprojection error, and confidence 1 - worst / 12 px.
    for shift in (3.0, 8.0, 30.0):
        tri = triangulate_clicked([(cams[0], px[0]), (cams[4], px[4] + [shift, shift])])
        assert tri.used == (1, 5) and max(tri.errors_px) > 0.5
        assert tri.confidence == pytest.approx(max(0.0, 1 - max(tri.errors_px) / TRIANGULATION_ZERO_CONF_PX))
    assert tri.confidence == 0.0  # 30 px apart: still offered (the page rings it), at confidence 0
    assert triangulated_proposal([(cams[0], px[0]), (cams[4], px[4] + [30.0, 30.0])], cams[2]) is not None


def test_a_projection_outside_the_image_is_not_offered():
    cams, point = _cameras(), np.array([0.0, 0.0, 0.0])
    px = _pixels(point)
    small = {**cams[2], "width": 8, "height": 8}  # the point lands far outside this view
    assert triangulated_proposal([(cams[0], px[0]), (cams[1], px[1])], small) is None


def test_a_source_point_outside_the_image_gives_way_to_the_next_source_as_in_the_browser():
    payload = {"cameras": [{"view_id": 1, "width": 100, "height": 80}],
               "sources": [{"kind": "fit", "confidences": None, "views": {"1": [[120.0, 10.0], [10.0, 10.0]]}},
                           {"kind": "detector", "confidences": [0.9, 0.9],
                            "views": {"1": [[99.0, 10.0], [20.0, 20.0]]}}]}
    assert offered_proposals(payload) == {(1, 0): (99.0, 10.0), (1, 1): (10.0, 10.0)}


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")
def test_the_port_gives_the_pages_numbers(tmp_path):
    """annotation.js's triangulateClicked and proposals() in node, against the port, on noisy clicks with a
    swapped view (the outlier pruning) and pairs of views (the confidence)."""
    for name in ("geometry.js", "annotation.js"):
        shutil.copy(FRONTEND_JS / name, tmp_path / name)
    (tmp_path / "package.json").write_text('{"type": "module"}')
    rng = np.random.default_rng(3)
    cams = _cameras()
    cases = []
    for _ in range(12):
        point = rng.uniform(-0.08, 0.08, 3)
        px = _pixels(point) + rng.normal(0, 2.0, (len(cams), 2))
        views = sorted(rng.choice(len(cams), int(rng.integers(2, 6)), replace=False).tolist())
        if len(views) >= 3 and rng.random() < 0.7:
            px[views[-1]] += rng.uniform(15, 40, 2)  # an outlier to prune
        cases.append({"views": [v + 1 for v in views], "pixels": {str(v + 1): px[v].tolist() for v in views}})
    script = """
import { Annotation, proposals, triangulateClicked } from "./annotation.js";
const { cams, cases } = JSON.parse(process.argv[2]);
const cameras = new Map(cams.map((c) => [c.view_id, c]));
const out = cases.map(({ views, pixels }) => {
  const ann = new Annotation(cams.map((c) => c.view_id), [0]);
  for (const v of views) ann.set(v, 0, { x: pixels[v][0], y: pixels[v][1], visibility: "visible" });
  const tri = triangulateClicked(ann, cameras, 0);
  const offered = proposals(ann, cameras, []);
  return { tri, offered: Object.fromEntries([...offered].map(([v, m]) => [v, m.get(0) || null])) };
});
console.log(JSON.stringify(out));
"""
    (tmp_path / "run.js").write_text(script)
    done = subprocess.run(["node", str(tmp_path / "run.js"), json.dumps({"cams": cams, "cases": cases})],
                          capture_output=True, text=True, timeout=60, check=True)
    results = json.loads(done.stdout)
    pruned = 0
    for case, js in zip(cases, results, strict=True):
        clicked = [(cams[v - 1], case["pixels"][str(v)]) for v in case["views"]]
        tri = triangulate_clicked(clicked)
        np.testing.assert_allclose(tri.point, js["tri"]["point"], atol=1e-9)
        np.testing.assert_allclose(tri.errors_px, js["tri"]["errors_px"], atol=1e-6)
        assert list(tri.used) == js["tri"]["used"]
        assert tri.confidence == pytest.approx(js["tri"]["confidence"], abs=1e-9)
        pruned += len(tri.used) < len(case["views"])
        for cam in cams:
            offered = js["offered"][str(cam["view_id"])]
            mine = None if cam["view_id"] in case["views"] else triangulated_proposal(clicked, cam)
            if offered is None:
                assert mine is None
            else:
                assert offered["source"] == "triangulated"
                np.testing.assert_allclose(mine, [offered["x"], offered["y"]], atol=1e-6)
    assert pruned > 0  # the outlier rule was exercised
