"""`handloop demo` serves the app: the printed URL answers, the printed admin logs in, the synthetic capture
is imported, and the embedded worker runs jobs (an admin's submission is fitted), with no server installed."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx

from backend.runtime import free_port

REPO = Path(__file__).resolve().parents[3]


def _read_until(process: subprocess.Popen, pattern: str, timeout_s: float) -> tuple[re.Match, str]:
    seen = ""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        if not line:
            if process.poll() is not None:
                break
            continue
        seen += line
        if match := re.search(pattern, seen):
            return match, seen
    raise AssertionError(f"{pattern!r} not printed within {timeout_s} s:\n{seen}")


def test_demo_prints_url_and_login_and_runs_api_and_worker(tmp_path):
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("HANDLOOP_")}
    env["HANDLOOP_DATA_DIR"] = str(tmp_path / "data")
    process = subprocess.Popen(
        [sys.executable, "-c", "from backend.cli.main import app; app(prog_name='handloop')", "demo",
         "--sequences", "1", "--frames", "2", "--width", "96", "--port", str(port)],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        login, _ = _read_until(process, r"login\s+: (\S+) / (\S+)", 300)
        url, output = _read_until(process, r"URL\s+: (http://\S+?)/ ", 300)
        assert "stand-in for MANO" in output
        # Round 0 pre-annotated by the worker where the detector is installed; "running" once it has ended.
        _, output = _read_until(process, r"running\s+: API \+ worker", 300)
        from workers.detector import detector_status

        problem = detector_status()
        assert ("round 0 : pre-annotation succeeded: 2 samples" if problem is None
                else f"pre-annotation off: {problem}") in output, output
        base = url.group(1)
        assert base == f"http://127.0.0.1:{port}"
        assert httpx.get(base + "/api/health", timeout=10).status_code == 200
        token = httpx.post(base + "/api/auth/token", data={"username": login.group(1), "password": login.group(2)},
                           timeout=30).json()["access_token"]
        http = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {token}"}, timeout=30)
        task = http.post("/api/annotate/next").json()  # the imported capture is in the annotators' queue
        # (at 96 px the detector finds no hand to fit: the pre-annotation handed both samples to the annotators)
        from workers.capture import load_ground_truth, read_capture

        capture = read_capture(tmp_path / "data" / "demo-capture", check_images=False)
        truth = load_ground_truth(capture.sequences[0].frames[task["frame_index"]])
        clicks = []
        for view in task["views"]:
            c = list(truth.camera_names).index(view["camera"])
            for k in task["keypoints_to_click"]:
                x, y = truth.keypoints_2d[c, k]
                seen = truth.visibility[c, k] and -0.5 <= x <= view["width"] - 0.5 and -0.5 <= y <= view["height"] - 0.5
                click = {"view_id": view["id"], "keypoint": k, "visibility": "not_annotated"}
                clicks.append({**click, "x": float(x), "y": float(y), "visibility": "visible"} if seen else click)
        submitted = http.post(f"/api/annotate/samples/{task['sample_id']}/submissions",
                              json={"submission_id": "demo-test-0001", "lease_token": task["lease_token"],
                                    "time_spent_s": 5.0, "clicks": clicks})
        assert submitted.status_code == 201, submitted.text
        job_id = submitted.json()["fit_job_id"]
        deadline = time.monotonic() + 240
        while (job := http.get(f"/api/admin/jobs/{job_id}").json())["state"] in ("queued", "running"):
            assert time.monotonic() < deadline, job
            time.sleep(0.5)
        assert job["state"] == "succeeded" and job["attempts"] == 1, job
        assert http.get(f"/api/admin/jobs/{job_id}").json()["result"]["fit_id"]
    finally:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            process.kill()
    assert process.returncode == 0, process.stdout.read()
