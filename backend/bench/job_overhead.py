"""`handloop bench jobs`: throughput of fit jobs through Celery against a direct batched call of the same fits.

Setup (not timed): a synthetic capture (cached), a fresh SQLite database with the capture imported, and one
annotator submission per sample through the real API (in-process), with clicks on the sparse keypoints
at their true projections plus Gaussian noise (2 px), so every sample has a queued fit job.

Per repeat, on its own samples (the two paths in alternating order):
- direct: the fits' inputs loaded beforehand, then `FittingEngine.fit` on batches of FIT_BATCH_SIZE in this
  process (engine built and warmed before the clock starts);
- Celery: the same jobs sent as `handloop.fit_batch` tasks of the same size to a real worker process
  (embedded filesystem broker by default, or Redis), clock from the first send until the last job row's
  finished_at: claiming, loading clicks and masks from the database and storage, fitting, storing model masks,
  recording fits (heuristic routing included) and the broker's latency.
`celery_overhead_pct` = 100 (t_celery / t_direct - 1) over all repeats; `handling_overhead_pct` compares
t_celery with the seconds the worker itself spent inside FittingEngine.fit, so the fits' run-to-run spread
(large on a shared machine) cancels out. Both paths use one torch thread.
"""

from __future__ import annotations

import logging
import os
import shutil
import sys
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

import numpy as np
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from backend.app import create_app
from backend.bench.common import emit
from backend.broker.celery_queue import TASK_FIT_BATCH, make_client_app
from backend.db.migrate import upgrade
from backend.db.session import create_engine_from_url, make_session_factory
from backend.models.capture import Sequence
from backend.models.enums import Role
from backend.models.jobs import Job
from backend.runtime import start_stack
from backend.services.accounts.users import create_user
from backend.services.captures.importer import import_capture
from backend.services.captures.storage import LocalDiskStorage
from backend.services.jobs.jobs import InMemoryJobQueue
from backend.settings import Settings
from workers.capture import CaptureError, load_ground_truth, read_capture
from workers.synth.generator import generate_capture
from workers.synth.plan import SynthConfig
from workers.tasks.context import build_context
from workers.tasks.fit_sources import fit_input
from workers.tasks.fits import engine_for, fit_config

log = logging.getLogger(__name__)

BENCH_SEED = 9002
CLICK_NOISE_PX = 2.0
PASSWORD = "bench-jobs-password"


def _capture(sequences: int, frames: int, width: int) -> Path:
    out = Path(tempfile.gettempdir()) / "handloop-bench-cache" / f"jobs-s{sequences}-f{frames}-w{width}-{BENCH_SEED}"
    if out.exists():
        try:
            read_capture(out, check_images=False)
            return out
        except CaptureError:
            pass
    log.info("synthesising %d x %d frames at %d px into %s", sequences, frames, width, out)
    generate_capture(out, SynthConfig(num_sequences=sequences, frames_per_sequence=frames, seed=BENCH_SEED,
                                      width_px=width), force=True)
    return out


def _submissions(settings: Any, capture_dir: Path, count: int) -> list[int]:
    """One GT-click submission per sample through the API (in-process, no broker): the fit job ids."""


    capture = read_capture(capture_dir, check_images=False)
    frames = {(s.id, f.index): f for s in capture.sequences for f in s.frames}
    rng = np.random.default_rng(BENCH_SEED)
    app = create_app(settings, job_queue=InMemoryJobQueue())
    job_ids = []
    with TestClient(app) as client:
        token = client.post("/api/auth/token", data={"username": "annotator@bench.local", "password": PASSWORD})
        client.headers["Authorization"] = f"Bearer {token.json()['access_token']}"
        sequences = {}


        with app.state.session_factory() as session:
            sequences = dict(session.execute(select(Sequence.id, Sequence.external_id)).all())
        for _ in range(count):
            task = client.post("/api/annotate/next").json()
            truth = load_ground_truth(frames[(sequences[task["sequence_id"]], task["frame_index"])])
            clicks = []
            for view in task["views"]:
                c = list(truth.camera_names).index(view["camera"])
                for k in task["keypoints_to_click"]:
                    x, y = truth.keypoints_2d[c, k] + rng.normal(0, CLICK_NOISE_PX, 2)
                    x, y = float(np.clip(x, 0, view["width"] - 1)), float(np.clip(y, 0, view["height"] - 1))
                    click = {"view_id": view["id"], "keypoint": k, "visibility": "not_annotated"}
                    clicks.append({**click, "x": x, "y": y, "visibility": "visible"} if truth.visibility[c, k]
                                  else click)
            response = client.post(f"/api/annotate/samples/{task['sample_id']}/submissions",
                                   json={"submission_id": uuid.uuid4().hex, "lease_token": task["lease_token"],
                                         "time_spent_s": 10.0, "clicks": clicks})
            response.raise_for_status()
            job_ids.append(response.json()["fit_job_id"])
    app.state.engine.dispose()
    return job_ids


def _wait_final(factory: Any, job_ids: list[int], timeout_s: float) -> tuple[dict[str, int], float]:
    """Wait until every job is final; their states and the last one's finish time (epoch seconds).

    Polled once a second: the end is read from the rows' finished_at, so the polling neither adds to the
    measured time nor takes CPU from the worker on a loaded machine."""


    deadline = time.monotonic() + timeout_s
    while True:
        with factory() as session:
            states = dict(session.execute(select(Job.state, func.count()).where(Job.id.in_(job_ids))
                                          .group_by(Job.state)).all())
            if states.get("queued", 0) + states.get("running", 0) == 0:
                last = session.execute(select(func.max(Job.finished_at)).where(Job.id.in_(job_ids))).scalar_one()
                return {str(k): int(v) for k, v in states.items()}, last.timestamp()
        if time.monotonic() > deadline:
            raise TimeoutError(f"fit jobs not final after {timeout_s} s: {states}")
        time.sleep(1.0)


def _direct(engine: Any, observations: list[Any], batch: int) -> float:
    """Seconds to fit `observations` in batches, in this process."""
    t0 = time.perf_counter()
    for start in range(0, len(observations), batch):
        engine.fit(observations[start:start + batch])
    return time.perf_counter() - t0


def _through_celery(client: Any, factory: Any, job_ids: list[int], batch: int
                    ) -> tuple[float, dict[str, int], float, float]:
    """Seconds from sending `job_ids` as fit_batch tasks until every job row is final, their states, the
    seconds the worker's fit service reported (claim, load, fit, record; without delivery) and the part of
    those inside FittingEngine.fit."""

    t0 = time.time()  # wall clock, as the rows' finished_at
    sent = [client.send_task(TASK_FIT_BATCH, args=[job_ids[start:start + batch]], queue="cpu")
            for start in range(0, len(job_ids), batch)]
    states, finished = _wait_final(factory, job_ids, 3600)
    elapsed = finished - t0
    results = [result.get(timeout=60) for result in sent]
    return elapsed, states, sum(r["seconds"] for r in results), sum(r["fit_seconds"] for r in results)


def run(*, quick: bool = False, emit_json: bool = False, broker: str = "embedded", batch_size: int | None = None,
        repeats: int | None = None) -> dict[str, Any]:
    started = time.perf_counter()
    batch = batch_size or 6
    repeats = repeats or (2 if quick else 4)
    per_repeat = batch if quick else 2 * batch
    width = 160 if quick else 320
    needed = repeats * per_repeat + 1  # + one warm-up sample for the worker
    sequences = 1 if quick else 2
    capture_dir = _capture(sequences, -(-needed // sequences), width)
    load_before = os.getloadavg()

    root = Path(tempfile.mkdtemp(prefix="handloop-bench-jobs-"))
    broker_url = None
    if broker == "redis":
        broker_url = os.environ.get("HANDLOOP_BENCH_REDIS_URL", "redis://127.0.0.1:6379/0")
    settings = Settings(data_dir=root / "data", environment="test", secret_key="bench-jobs-secret-key-0123",
                        broker_url=broker_url, broker_prefix=f"bench-jobs-{uuid.uuid4().hex[:8]}:",
                        fit_batch_size=batch, worker_torch_threads=1, worker_concurrency=1)
    stack = None
    try:
        settings.data_dir.mkdir(parents=True)
        upgrade(settings.resolved_database_url)
        factory = make_session_factory(create_engine_from_url(settings.resolved_database_url))
        with factory.begin() as session:
            import_capture(session, LocalDiskStorage(settings.storage_dir), capture_dir, project_name="bench")
            create_user(session, "annotator@bench.local", PASSWORD, Role.annotator)
        print(f"[bench jobs] {needed} submissions through the API ...", file=sys.stderr)
        job_ids = _submissions(settings, capture_dir, needed)
        warmup, job_ids = job_ids[0], job_ids[1:]

        print("[bench jobs] starting the worker ...", file=sys.stderr)
        stack = start_stack(settings, start_api=False, worker_queues=("cpu",))
        client = make_client_app(settings)
        client.send_task(TASK_FIT_BATCH, args=[[warmup]], queue="cpu")
        _wait_final(factory, [warmup], 600)
        time.sleep(2.0)  # the worker's fit cache and the file system settle

        ctx = build_context(settings, job_queue=InMemoryJobQueue())
        config = fit_config(ctx, "annotation")
        rows = []
        for r in range(repeats):
            subset = job_ids[r * per_repeat:(r + 1) * per_repeat]
            with ctx.session_factory() as session:
                inputs = [fit_input(ctx, session, session.get(Job, j)) for j in subset]
            engine = engine_for(ctx, inputs[0], config)
            if r == 0:
                engine.fit([inputs[0].observations])  # warm-up, like the worker's first task

            # Alternate the order: the machine's load drifts, and neither path should always go first.
            if r % 2 == 0:
                t_direct = _direct(engine, [fi.observations for fi in inputs], batch)
                t_celery, states, t_service, t_engine = _through_celery(client, factory, subset, batch)
            else:
                t_celery, states, t_service, t_engine = _through_celery(client, factory, subset, batch)
                t_direct = _direct(engine, [fi.observations for fi in inputs], batch)
            print(f"[bench jobs] repeat {r + 1}: {len(subset)} fits, direct {t_direct:.1f} s, Celery {t_celery:.1f} s "
                  f"{states}", file=sys.stderr)
            rows.append({"fits": len(subset), "direct_s": round(t_direct, 3), "celery_s": round(t_celery, 3),
                         "worker_service_s": round(t_service, 3), "worker_engine_s": round(t_engine, 3),
                         "job_states": states, "load_avg_1min": round(os.getloadavg()[0], 2)})
        total_direct = sum(row["direct_s"] for row in rows)
        total_celery = sum(row["celery_s"] for row in rows)
        n = sum(row["fits"] for row in rows)
        ratios = sorted(row["celery_s"] / row["direct_s"] for row in rows)
        result = {
            "celery_overhead_pct": round(100 * (total_celery / total_direct - 1), 2),
            # The machine's load drifts between repeats: the median of per-repeat ratios is the steadier figure.
            "celery_overhead_pct_median": round(100 * (float(np.median(ratios)) - 1), 2),
            # What Celery and the job services add to the same process's fitting time (broker, claim, loading,
            # recording): immune to the fits' own run-to-run spread on a loaded machine.
            "handling_overhead_pct": round(100 * (total_celery / sum(row["worker_engine_s"] for row in rows) - 1), 2),
            "worker_service_s": round(sum(row["worker_service_s"] for row in rows), 3),
            "worker_engine_s": round(sum(row["worker_engine_s"] for row in rows), 3),
            "fits_per_s_celery": round(n / total_celery, 4),
            "fits_per_s_direct": round(n / total_direct, 4),
            "fits": n,
            "failed_fits": sum(row["job_states"].get("failed", 0) for row in rows),
            "repeats": rows,
            "load_avg_before": [round(v, 2) for v in load_before],
            "load_avg_after": [round(v, 2) for v in os.getloadavg()],
        }
        run_settings = {"quick": quick, "broker": broker, "batch_size": batch, "fits_per_repeat": per_repeat,
                        "width_px": width, "views": 8, "click_noise_px": CLICK_NOISE_PX,
                        "iterations": [config.global_iterations, config.full_iterations], "torch_threads": 1,
                        "worker_concurrency": 1, "capture": capture_dir.name}
        record = {**result, "settings": run_settings}
        if emit_json:
            record = emit("jobs", result, run_settings, started)
        return record
    finally:
        if stack is not None:
            stack.stop()
        shutil.rmtree(root, ignore_errors=True)
