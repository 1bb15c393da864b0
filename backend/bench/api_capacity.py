"""`handloop bench api`: simulated annotators against a real server on PostgreSQL.

A fresh database is created and migrated, seeded with samples (rows only, no images) and annotator
accounts; uvicorn (uvloop, httptools) serves the app on 127.0.0.1, with the scale-out broker (Redis, under a
key prefix of its own, removed afterwards) receiving the fit jobs that submissions queue. N simulated
annotators, coroutines in this one process with one keep-alive HTTP/1.1 connection each (so at most N
requests in flight), loop next -> submit until the time is up:
- paced (`rate` > 0, the default 200 submissions/s): each annotator starts a cycle every N / rate seconds
  on a fixed schedule (staggered), so the server is offered the target load and the latencies are those at
  that load; an annotator behind schedule starts at once, and how far behind is reported (schedule lag);
- saturated (`rate` = 0): every annotator starts its next cycle as soon as the last one ends, so
  throughput is the server's capacity and latency is queueing (p50 ~ N / (2 x submits/s), Little's law).
Afterwards the database is checked: every acknowledged submission must be there with all its clicks
(lost_submissions) and no sample may have been handed to two annotators (duplicate_assignments).
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import redis
from sqlalchemy import create_engine, insert, text

from backend.db.migrate import upgrade
from backend.db.session import create_engine_from_url, make_session_factory
from backend.models.enums import Role
from backend.models.users import User
from backend.services.security import hash_password
from backend.services.seed import seed_samples

logger = logging.getLogger(__name__)

SECRET = "bench-secret-key-not-for-production"
PASSWORD = "bench-password-123"


@dataclass
class AnnotatorLog:
    latencies_ms: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    assigned: list[int] = field(default_factory=list)
    acknowledged: list[tuple[str, int, int]] = field(default_factory=list)  # client id, sample id, clicks
    errors: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    queue_empty: bool = False
    lag_ms: list[float] = field(default_factory=list)  # paced runs: how late each cycle started


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _percentile(values: list[float], q: float) -> float | None:
    return round(float(np.percentile(values, q)), 2) if values else None


def _seed(url: str, annotators: int, samples: int, cameras: int, width: int) -> None:
    upgrade(url)
    engine = create_engine_from_url(url)
    hashed = hash_password(PASSWORD)
    with make_session_factory(engine).begin() as session:
        session.execute(insert(User), [{"email": f"annotator{i}@bench.local", "full_name": "", "role": Role.annotator,
                                        "hashed_password": hashed} for i in range(annotators)])
        per_seq = 500
        for s in range((samples + per_seq - 1) // per_seq):
            seed_samples(session, project=f"bench{s}", frames=min(per_seq, samples - s * per_seq), cameras=cameras,
                         width=width, height=width)
    engine.dispose()


def _verify(url: str, logs: list[AnnotatorLog]) -> tuple[int, int]:
    """(duplicate assignments, lost submissions) from what the clients saw and what the database holds."""

    holders: dict[int, set[int]] = defaultdict(set)
    for i, log in enumerate(logs):
        for sample_id in log.assigned:
            holders[sample_id].add(i)
    duplicates = sum(1 for h in holders.values() if len(h) > 1)  # leases outlive the run: one holder each
    engine = create_engine(url)
    with engine.connect() as conn:
        stored = {row[0]: (row[1], row[2]) for row in conn.execute(text(
            "SELECT s.client_id, s.sample_id, count(c.id) FROM submissions s "
            "LEFT JOIN clicks c ON c.submission_id = s.id GROUP BY s.client_id, s.sample_id"))}
    engine.dispose()
    lost = sum(1 for log in logs for cid, sid, n in log.acknowledged if stored.get(cid) != (sid, n))
    return duplicates, lost


def run(annotators: int = 50, seconds: float = 30.0, *, rate: float = 200.0, samples: int | None = None,
        cameras: int = 8, server_workers: int = 2,
        pg_admin_url: str = "postgresql+psycopg://postgres@127.0.0.1:5432/postgres",
        broker_url: str = "redis://127.0.0.1:6379/15", width: int = 320, warmup_s: float = 3.0) -> dict[str, Any]:
    """One measured run; `rate` offered submissions/s in total (0: saturate)."""

    samples = samples or max(2000, int(400 * (seconds + warmup_s)))
    prefix = f"handloop-bench-{uuid.uuid4().hex[:8]}:"
    db_name = f"handloop_bench_{uuid.uuid4().hex[:8]}"
    admin = create_engine(pg_admin_url, isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{db_name}"'))
    url = pg_admin_url.rsplit("/", 1)[0] + f"/{db_name}"
    server = None
    try:
        t0 = time.perf_counter()
        _seed(url, annotators, samples, cameras, width)
        logger.info("seeded %d samples x %d views and %d annotators in %.1f s", samples, cameras, annotators,
                    time.perf_counter() - t0)
        port = _free_port()
        pool = max(5, annotators // server_workers + 5)
        env = {**os.environ, "HANDLOOP_DATABASE_URL": url, "HANDLOOP_SECRET_KEY": SECRET,
               "HANDLOOP_ENVIRONMENT": "production", "HANDLOOP_DB_POOL_SIZE": str(pool),
               "HANDLOOP_DB_MAX_OVERFLOW": "5", "HANDLOOP_DATA_DIR": tempfile.mkdtemp(prefix="handloop-bench-"),
               "HANDLOOP_BROKER_URL": broker_url, "HANDLOOP_BROKER_PREFIX": prefix}
        server = subprocess.Popen(
            [sys.executable, "-m", "uvicorn", "backend.app:create_app", "--factory", "--host", "127.0.0.1",
             "--port", str(port), "--workers", str(server_workers), "--loop", "uvloop", "--http", "httptools",
             # the logins (Argon2) take longer than uvicorn's default 5 s keep-alive: keep the connections open
             "--timeout-keep-alive", "120", "--no-access-log", "--log-level", "warning"],
            env=env, cwd=Path(__file__).resolve().parents[2])
        base = f"http://127.0.0.1:{port}"
        _wait_ready(base, server)
        logs = [AnnotatorLog() for _ in range(annotators)]
        warmup_logs = [AnnotatorLog() for _ in range(annotators)]
        load_before = os.getloadavg()[0]
        elapsed = _drive(port, logs, seconds, rate, warmup_logs, warmup_s)
        load_after = os.getloadavg()[0]
        duplicates, lost = _verify(url, warmup_logs + logs)
    finally:
        if server is not None:
            server.terminate()
            try:
                server.wait(15)
            except subprocess.TimeoutExpired:
                server.kill()
        with admin.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{db_name}" WITH (FORCE)'))
        admin.dispose()
        fit_messages = _drop_broker_keys(broker_url, prefix)

    lat = {route: [x for log in logs for x in log.latencies_ms[route]] for route in ("next", "submit")}
    submits = sum(len(log.acknowledged) for log in logs)
    errors: dict[str, int] = defaultdict(int)
    for log in logs:
        for key, n in log.errors.items():
            errors[key] += n
    lag = [x for log in logs for x in log.lag_ms]
    return {
        "mode": f"paced, {rate:g} submissions/s offered" if rate > 0 else "saturated",
        "p50_ms_next": _percentile(lat["next"], 50), "p99_ms_next": _percentile(lat["next"], 99),
        "p50_ms_submit": _percentile(lat["submit"], 50), "p99_ms_submit": _percentile(lat["submit"], 99),
        "submits_per_s": round(submits / elapsed, 1), "requests_per_s": round(sum(map(len, lat.values())) / elapsed, 1),
        "submits": submits, "duplicate_assignments": duplicates, "lost_submissions": lost,
        "errors": dict(errors), "queue_exhausted": any(log.queue_empty for log in logs),
        "measured_s": round(elapsed, 2), "warmup_s": warmup_s, "clicks_per_submit": cameras * 6,
        "p99_ms_schedule_lag": _percentile(lag, 99) if rate > 0 else None,
        "fit_messages_queued": fit_messages,
        "load_average_1min": {"before": round(load_before, 2), "after": round(load_after, 2)},
        "client": f"{annotators} asyncio coroutines in one process, one HTTP/1.1 keep-alive connection each",
        "server": f"uvicorn --workers {server_workers} --loop uvloop --http httptools --timeout-keep-alive 120, "
                  f"db pool {pool}+5 per worker",
    }


class _Http:
    """A minimal HTTP/1.1 keep-alive client on one connection (asyncio streams): a simulated annotator's
    browser tab. Much lighter than httpx, so the load generator leaves the two cores to the server."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.reader: asyncio.StreamReader | None = None
        self.writer: asyncio.StreamWriter | None = None
        self.auth = b""

    async def request(self, method: str, path: str, body: bytes = b"",
                      content_type: bytes = b"application/json") -> tuple[int, bytes]:
        if self.writer is None:
            self.reader, self.writer = await asyncio.open_connection("127.0.0.1", self.port)
        assert self.reader is not None
        self.writer.write(b"%s %s HTTP/1.1\r\nHost: 127.0.0.1\r\n%sContent-Type: %s\r\nContent-Length: %d\r\n\r\n%s"
                          % (method.encode(), path.encode(), self.auth, content_type, len(body), body))
        head = await self.reader.readuntil(b"\r\n\r\n")
        status = int(head[9:12])
        length = 0
        for line in head.split(b"\r\n")[1:]:
            if line[:15].lower() == b"content-length:":
                length = int(line[15:])
        return status, await self.reader.readexactly(length) if length else b""

    async def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            await self.writer.wait_closed()


def _drop_broker_keys(broker_url: str, prefix: str) -> int | None:
    """Remove the run's Redis keys (no worker consumes the fit jobs here); returns the fit messages queued."""
    try:
        client = redis.Redis.from_url(broker_url)
        queued = int(client.llen(f"{prefix}cpu"))
        keys = list(client.scan_iter(match=f"{prefix}*"))
        if keys:
            client.delete(*keys)
        client.close()
        return queued
    except Exception as exc:  # the figures stand without this count
        logger.warning("could not clean the broker keys %s*: %s", prefix, exc)
        return None


def _drive(port: int, logs: list[AnnotatorLog], seconds: float, rate: float, warmup_logs: list[AnnotatorLog],
           warmup_s: float) -> float:
    """Run the simulated annotators as coroutines in this process (uvloop when installed); returns the
    measured seconds. Logins (Argon2) happen first, 4 at a time; the clock starts when all are in."""
    try:
        import uvloop  # deferred: optional (uvicorn[standard] brings it), asyncio's loop without it
        runner: Any = uvloop.run
    except ImportError:
        runner = asyncio.run
    return runner(_drive_async(port, logs, seconds, rate, warmup_logs, warmup_s))


async def _drive_async(port: int, logs: list[AnnotatorLog], seconds: float, rate: float,
                       warmup_logs: list[AnnotatorLog], warmup_s: float) -> float:
    clients = [_Http(port) for _ in logs]
    gate = asyncio.Semaphore(4)

    async def login(i: int) -> None:
        async with gate:
            status, body = await clients[i].request(
                "POST", "/api/auth/token", f"username=annotator{i}%40bench.local&password={PASSWORD}".encode(),
                b"application/x-www-form-urlencoded")
            if status != 200:
                raise RuntimeError(f"login of annotator{i} failed: {status} {body[:200]!r}")
            clients[i].auth = b"Authorization: Bearer %s\r\n" % json.loads(body)["access_token"].encode()

    await asyncio.gather(*(login(i) for i in range(len(logs))))
    cycle_s = len(logs) / rate if rate > 0 else 0.0

    async def phase(phase_logs: list[AnnotatorLog], duration_s: float) -> float:
        start = time.perf_counter()
        await asyncio.gather(*(_annotator(clients[i], i, start + duration_s, phase_logs[i],
                                          start + cycle_s * i / len(logs), cycle_s) for i in range(len(logs))))
        return time.perf_counter() - start

    # Warm-up, not measured (its assignments and submissions are verified with the rest): the server's
    # connection pools fill and PostgreSQL prepares the statements, as in a server that has been running.
    await phase(warmup_logs, warmup_s)
    elapsed = await phase(logs, seconds)
    for client in clients:
        await client.close()
    return elapsed


async def _annotator(client: _Http, index: int, deadline: float, log: AnnotatorLog, first_s: float,
                     cycle_s: float) -> None:
    """One simulated annotator: next -> submit until the deadline (one request in flight at a time); with
    `cycle_s` > 0 a cycle starts every `cycle_s` seconds from `first_s`, at once when behind schedule."""
    scheduled = first_s
    while time.perf_counter() < deadline:
        if cycle_s > 0:
            if scheduled >= deadline:
                return
            wait = scheduled - time.perf_counter()
            if wait > 0:
                await asyncio.sleep(wait)
            log.lag_ms.append(max(0.0, -wait) * 1000)
            scheduled += cycle_s
        t0 = time.perf_counter()
        status, body = await client.request("POST", "/api/annotate/next")
        log.latencies_ms["next"].append((time.perf_counter() - t0) * 1000)
        if status == 204:
            log.queue_empty = True
            return
        if status != 200:
            log.errors[f"next:{status}"] += 1
            continue
        task = json.loads(body)
        log.assigned.append(task["sample_id"])
        clicks = [{"view_id": v["id"], "keypoint": k, "x": 10.0 + k, "y": 20.0 + index % 7,
                   "visibility": "visible"} for v in task["views"] for k in task["keypoints_to_click"]]
        client_id = uuid.uuid4().hex
        payload = json.dumps({"submission_id": client_id, "lease_token": task["lease_token"], "time_spent_s": 30.0,
                              "clicks": clicks}).encode()
        t0 = time.perf_counter()
        status, body = await client.request("POST", f"/api/annotate/samples/{task['sample_id']}/submissions", payload)
        log.latencies_ms["submit"].append((time.perf_counter() - t0) * 1000)
        if status in (200, 201):
            log.acknowledged.append((client_id, task["sample_id"], len(clicks)))
        else:
            log.errors[f"submit:{status}"] += 1


def _wait_ready(base: str, server: subprocess.Popen, timeout_s: float = 60.0) -> None:
    end = time.perf_counter() + timeout_s
    while time.perf_counter() < end:
        if server.poll() is not None:
            raise RuntimeError(f"uvicorn exited with code {server.returncode}")
        try:
            if httpx.get(f"{base}/api/health", timeout=1.0).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    raise RuntimeError("uvicorn did not become ready")
