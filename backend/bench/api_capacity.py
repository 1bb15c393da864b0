"""`handloop bench api`: simulated annotators against a real server on PostgreSQL or the embedded SQLite.

A fresh database is created and migrated (PostgreSQL: a database beside the maintenance one; SQLite: a file
in a temporary folder), seeded with samples (rows only, no images) and annotator accounts; uvicorn (uvloop,
httptools) serves the app on 127.0.0.1, with a broker receiving the fit jobs that submissions queue
(PostgreSQL: the scale-out Redis broker under a key prefix of its own, removed afterwards; SQLite: the
embedded filesystem broker, as in the demo). N simulated annotators, coroutines in this one process with one
keep-alive HTTP/1.1 connection each (so at most N requests in flight) and a token signed with the server's
key (N Argon2 logins would take minutes and are not what is measured), loop next -> submit until the time
is up:
- paced (`rate` > 0, the default 200 submissions/s): each annotator starts a cycle every N / rate seconds
  on a fixed schedule (staggered), so the server is offered the target load and the latencies are those at
  that load; an annotator behind schedule starts at once, and how far behind is reported (schedule lag);
- saturated (`rate` = 0): every annotator starts its next cycle as soon as the last one ends, so
  throughput is the server's capacity and latency is queueing (p50 ~ N / (2 x submits/s), Little's law).
Afterwards the database is checked: every acknowledged submission must be there with all its clicks
(lost_submissions) and no sample may have been handed to two annotators (duplicate_assignments).

CPU per cycle (`cpu_ms_per_cycle`, the figure that does not depend on the machine's load): the CPU time
(utime + stime from /proc) that the server's processes and the run's PostgreSQL backends (those connected to
the run's database, found in pg_stat_activity) used during the measured window, divided by the cycles
(acknowledged submissions) in it. PostgreSQL's shared background processes (WAL writer, checkpointer) are
not counted: they serve other databases on a shared machine too. The probe (`probe=True`) is the run that
measures it alone: one annotator, one server worker, saturated.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import shutil
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
from sqlalchemy import Engine, create_engine, insert, select, text

from backend.db.migrate import upgrade
from backend.db.session import create_engine_from_url, make_session_factory
from backend.models.enums import Role
from backend.models.users import User
from backend.services.accounts.security import create_token, hash_password
from backend.services.captures.seed import seed_samples
from backend.settings import Settings

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


DATABASES = ("postgres", "sqlite")
CROWD_CYCLE_S = 20.0  # a human pace: one next -> submit per annotator every 20 s


def _seed(url: str, annotators: int, samples: int, cameras: int, width: int) -> list[int]:
    """Migrate and seed; returns the annotators' user ids in order."""


    upgrade(url)
    engine = create_engine_from_url(url)
    hashed = hash_password(PASSWORD)
    emails = [f"annotator{i}@bench.local" for i in range(annotators)]
    with make_session_factory(engine).begin() as session:
        session.execute(insert(User), [{"email": email, "full_name": "", "role": Role.annotator,
                                        "hashed_password": hashed} for email in emails])
        per_seq = 500
        for s in range((samples + per_seq - 1) // per_seq):
            seed_samples(session, project=f"bench{s}", frames=min(per_seq, samples - s * per_seq), cameras=cameras,
                         width=width, height=width)
        ids = dict(session.execute(select(User.email, User.id).where(User.email.in_(emails))).all())
    if engine.dialect.name == "postgresql":  # statistics, as autovacuum keeps them in a server that has been running
        _analyze_seeded_tables(engine)
    engine.dispose()
    return [ids[email] for email in emails]


def _analyze_seeded_tables(engine: Engine) -> None:
    """ANALYZE the tables the seed filled, and only those. An analyzed empty table reads to PostgreSQL (14 and
    later) as truly empty, so the plans its backends cache for the foreign-key checks (clicks -> submissions,
    submissions -> jobs) scan it sequentially for as long as they live, while the run fills it: per submission 48
    scans of a growing table, most of the database's CPU in a 30 s run. A never-analyzed table is planned as
    at least 10 pages (an index scan), and autovacuum does not analyze a table before 50 rows have changed, so
    a server that has been running never holds that state."""
    with engine.connect().execution_options(isolation_level="AUTOCOMMIT") as conn:
        tables = conn.execute(text("SELECT tablename FROM pg_tables WHERE schemaname = current_schema()")).scalars()
        for table in list(tables):
            quoted = engine.dialect.identifier_preparer.quote(table)
            if conn.exec_driver_sql(f"SELECT EXISTS (SELECT FROM {quoted})").scalar():
                conn.exec_driver_sql(f"ANALYZE {quoted}")


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


def _cpu_ticks(pid: int, *, reaped: bool = False) -> int | None:
    """utime + stime of a process (all its threads), in clock ticks; with `reaped`, cutime + cstime instead: what
    its children that it has waited for used in all. None if it is gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()
    except OSError:
        return None
    first = 13 if reaped else 11  # fields 14-15 (16-17 reaped) of proc(5), counted after the ')'
    return int(fields[first]) + int(fields[first + 1])


def _parent(pid: int) -> int | None:
    """The parent's pid of a process; None if it is gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return int(f.read().rsplit(b")", 1)[1].split()[1])
    except (OSError, ValueError, IndexError):
        return None


def _descendants(root: int) -> list[int]:
    """`root` and every process below it (uvicorn's supervisor and its workers)."""
    children: dict[int, list[int]] = defaultdict(list)
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (ppid := _parent(int(entry))) is not None:
            children[ppid].append(int(entry))
    found, todo = [], [root]
    while todo:
        pid = todo.pop()
        found.append(pid)
        todo.extend(children.get(pid, ()))
    return found


def _machine_busy_ticks() -> int:
    """Clock ticks every CPU of the machine spent busy since boot (/proc/stat's first line: user, nice,
    system, irq, softirq; idle, iowait and steal, time the guest did not run, are not busy)."""
    with open("/proc/stat", "rb") as f:
        user, nice, system, _idle, _iowait, irq, softirq = map(int, f.readline().split()[1:8])
    return user + nice + system + irq + softirq


class CpuMeter:
    """CPU seconds used between `start` and `stop` by the server's process tree and by the PostgreSQL
    backends connected to the run's database (`backend_pids`: None on SQLite, where the database is in the
    server's processes). A process first seen at `stop` counts from zero (it was forked meanwhile). A backend
    that exits meanwhile (a pool's overflow connection closed at check-in, perhaps opened after `start` too) is
    counted from what the postmaster, its parent, has reaped: its children's CPU in all, less what the exited
    backends had used before `start`; an autovacuum worker or another database's session ending in the window
    is counted with them. `machine_s`, the whole machine's busy CPU over the same window, is kept beside them as
    a check, and `sessions` (a callable returning the run's database's session count) gives `sessions_opened`."""

    def __init__(self, server_pid: int, backend_pids: Any = None, sessions: Any = None) -> None:
        self.server_pid, self.backend_pids, self.sessions = server_pid, backend_pids, sessions
        self.ticks_per_s = os.sysconf("SC_CLK_TCK")
        self._start: tuple[dict[int, int], dict[int, int]] | None = None
        self._start_machine = self._start_sessions = self._start_reaped = 0
        self._postmaster: int | None = None
        self.server_s = self.db_s = self.machine_s = 0.0
        self.sessions_opened: int | None = None

    def _sample(self) -> tuple[dict[int, int], dict[int, int]]:
        def ticks(pids: list[int]) -> dict[int, int]:
            return {pid: t for pid in pids if (t := _cpu_ticks(pid)) is not None}
        return ticks(_descendants(self.server_pid)), ticks(self.backend_pids() if self.backend_pids else [])

    def _reaped(self) -> int:
        return (_cpu_ticks(self._postmaster, reaped=True) or 0) if self._postmaster else 0

    def start(self) -> None:
        self._start_sessions = self.sessions() if self.sessions else 0
        self._start_machine = _machine_busy_ticks()
        self._start = self._sample()
        self._postmaster = next(iter(filter(None, map(_parent, self._start[1]))), None)
        self._start_reaped = self._reaped()

    def stop(self) -> None:
        assert self._start is not None
        end = self._sample()
        reaped = self._reaped() - self._start_reaped
        self.machine_s = (_machine_busy_ticks() - self._start_machine) / self.ticks_per_s
        server, db = (sum(t - before.get(pid, 0) for pid, t in after.items())
                      for before, after in zip(self._start, end, strict=True))
        exited_before_start = sum(t for pid, t in self._start[1].items() if pid not in end[1])
        self.server_s = server / self.ticks_per_s
        self.db_s = (db + max(0, reaped - exited_before_start)) / self.ticks_per_s
        if self.sessions:
            self.sessions_opened = self.sessions() - self._start_sessions


def _per_cycle_ms(seconds: float, cycles: int) -> float | None:
    return round(1000 * seconds / cycles, 2) if cycles else None


def run(annotators: int = 50, seconds: float = 30.0, *, rate: float = 200.0, samples: int | None = None,
        cameras: int = 8, server_workers: int = 2, database: str = "postgres",
        pg_admin_url: str = "postgresql+psycopg://postgres@127.0.0.1:5432/postgres",
        broker_url: str = "redis://127.0.0.1:6379/15", width: int = 320, warmup_s: float = 3.0,
        db_pool: int | None = None) -> dict[str, Any]:
    """One measured run; `rate` offered submissions/s in total (0: saturate); `database` "postgres" (with
    the Redis broker at `broker_url`) or "sqlite" (with the embedded broker); `db_pool` a fixed pool of
    that many connections per server worker (None: the server's default, backend/settings.py)."""

    if database not in DATABASES:
        raise ValueError(f"database must be one of {', '.join(DATABASES)}, not {database!r}")
    if db_pool is not None and db_pool < 1:
        raise ValueError(f"db_pool must be at least 1 connection per worker, not {db_pool}")
    samples = samples or max(2000, int(400 * (seconds + warmup_s)) if rate <= 0 else
                             int(1.5 * rate * (seconds + warmup_s)) + 2 * annotators)
    prefix = f"handloop-bench-{uuid.uuid4().hex[:8]}:"
    db_name = f"handloop_bench_{uuid.uuid4().hex[:8]}"
    data_dir = Path(tempfile.mkdtemp(prefix="handloop-bench-"))
    admin = None
    if database == "postgres":
        admin = create_engine(pg_admin_url, isolation_level="AUTOCOMMIT")
        with admin.connect() as conn:
            conn.execute(text(f'CREATE DATABASE "{db_name}"'))
        url = pg_admin_url.rsplit("/", 1)[0] + f"/{db_name}"
    else:
        url = f"sqlite:///{data_dir / 'handloop.sqlite3'}"
    server = None
    try:
        t0 = time.perf_counter()
        user_ids = _seed(url, annotators, samples, cameras, width)
        logger.info("seeded %d samples x %d views and %d annotators in %.1f s", samples, cameras, annotators,
                    time.perf_counter() - t0)
        port = _free_port()
        # The server's own default pool (backend/settings.py), or a fixed one of `db_pool`.
        pool = db_pool or Settings.model_fields["db_pool_size"].default
        overflow = 0 if db_pool else Settings.model_fields["db_max_overflow"].default
        env = {**os.environ, "HANDLOOP_DATABASE_URL": url, "HANDLOOP_SECRET_KEY": SECRET,
               "HANDLOOP_ENVIRONMENT": "production", "HANDLOOP_DB_POOL_SIZE": str(pool),
               "HANDLOOP_DB_MAX_OVERFLOW": str(overflow), "HANDLOOP_DATA_DIR": str(data_dir)}
        env.pop("HANDLOOP_BROKER_URL", None)
        env.pop("HANDLOOP_BROKER_PREFIX", None)
        if database == "postgres":
            env.update({"HANDLOOP_BROKER_URL": broker_url, "HANDLOOP_BROKER_PREFIX": prefix})
        server = subprocess.Popen(
            [sys.executable, "-m", "uvicorn", "backend.app:create_app", "--factory", "--host", "127.0.0.1",
             "--port", str(port), "--workers", str(server_workers), "--loop", "uvloop", "--http", "httptools",
             # idle annotators (the crowd) must keep their connections, as browsers' tabs do
             "--timeout-keep-alive", "120", "--no-access-log", "--log-level", "warning", "--no-proxy-headers"],
            env=env, cwd=Path(__file__).resolve().parents[2])
        base = f"http://127.0.0.1:{port}"
        _wait_ready(base, server)

        def backend_pids() -> list[int]:
            assert admin is not None
            with admin.connect() as conn:
                return list(conn.execute(text("SELECT pid FROM pg_stat_activity WHERE datname = :db"),
                                         {"db": db_name}).scalars())

        def sessions() -> int:  # PostgreSQL >= 14 counts the sessions established to each database
            assert admin is not None
            with admin.connect() as conn:
                return int(conn.execute(text("SELECT sessions FROM pg_stat_database WHERE datname = :db"),
                                        {"db": db_name}).scalar_one())

        meter = (CpuMeter(server.pid, backend_pids, sessions) if database == "postgres" else CpuMeter(server.pid))
        logs = [AnnotatorLog() for _ in range(annotators)]
        warmup_logs = [AnnotatorLog() for _ in range(annotators)]
        tokens = [create_token(SECRET, uid, 0, 24 * 3600) for uid in user_ids]
        load_before = os.getloadavg()[0]
        client_cpu: list[float] = []
        elapsed = _drive(port, tokens, logs, seconds, rate, warmup_logs, warmup_s, meter, client_cpu)
        load_after = os.getloadavg()[0]
        duplicates, lost = _verify(url, warmup_logs + logs)
    finally:
        if server is not None:
            server.terminate()
            try:
                server.wait(15)
            except subprocess.TimeoutExpired:
                server.kill()
        if admin is not None:
            with admin.connect() as conn:
                conn.execute(text(f'DROP DATABASE IF EXISTS "{db_name}" WITH (FORCE)'))
            admin.dispose()
        fit_messages = (_drop_broker_keys(broker_url, prefix) if database == "postgres"
                        else _embedded_messages(data_dir))
        shutil.rmtree(data_dir, ignore_errors=True)

    lat = {route: [x for log in logs for x in log.latencies_ms[route]] for route in ("next", "submit")}
    submits = sum(len(log.acknowledged) for log in logs)
    errors: dict[str, int] = defaultdict(int)
    for log in logs:
        for key, n in log.errors.items():
            errors[key] += n
    lag = [x for log in logs for x in log.lag_ms]
    return {
        "mode": f"paced, {rate:g} submissions/s offered" if rate > 0 else "saturated",
        "database": "postgresql" if database == "postgres" else "sqlite",
        "cpu_ms_per_cycle": _per_cycle_ms(meter.server_s + meter.db_s, submits),
        "server_cpu_ms_per_cycle": _per_cycle_ms(meter.server_s, submits),
        "db_cpu_ms_per_cycle": _per_cycle_ms(meter.db_s, submits) if database == "postgres" else None,
        "client_cpu_ms_per_cycle": _per_cycle_ms(client_cpu[0], submits) if client_cpu else None,
        # everything busy on the machine (this client, the database's shared writers, other tenants included)
        "machine_cpu_ms_per_cycle": _per_cycle_ms(meter.machine_s, submits),
        "db_sessions_opened": meter.sessions_opened,
        "wall_ms_per_cycle": _per_cycle_ms(elapsed * annotators, submits) if rate <= 0 else None,
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
                  f"db pool {pool}+{overflow} per worker",
    }


def _embedded_messages(data_dir: Path) -> int | None:
    """Fit messages waiting in the embedded broker's folder (no worker consumes them here)."""
    folder = data_dir / "broker" / "messages"
    return sum(1 for _ in folder.iterdir()) if folder.is_dir() else None


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


def _drive(port: int, tokens: list[str], logs: list[AnnotatorLog], seconds: float, rate: float,
           warmup_logs: list[AnnotatorLog], warmup_s: float, meter: CpuMeter, client_cpu: list[float]) -> float:
    """Run the simulated annotators as coroutines in this process (uvloop when installed); returns the
    measured seconds. `meter` measures the server's CPU over the measured window; this process's own CPU
    over it is appended to `client_cpu`."""
    try:
        import uvloop  # deferred: optional (uvicorn[standard] brings it), asyncio's loop without it
        runner: Any = uvloop.run
    except ImportError:
        runner = asyncio.run
    return runner(_drive_async(port, tokens, logs, seconds, rate, warmup_logs, warmup_s, meter, client_cpu))


async def _drive_async(port: int, tokens: list[str], logs: list[AnnotatorLog], seconds: float, rate: float,
                       warmup_logs: list[AnnotatorLog], warmup_s: float, meter: CpuMeter,
                       client_cpu: list[float]) -> float:
    clients = [_Http(port) for _ in logs]
    for client, token in zip(clients, tokens, strict=True):
        client.auth = b"Authorization: Bearer %s\r\n" % token.encode()
    cycle_s = len(logs) / rate if rate > 0 else 0.0

    async def phase(phase_logs: list[AnnotatorLog], duration_s: float) -> float:
        start = time.perf_counter()
        await asyncio.gather(*(_annotator(clients[i], i, start + duration_s, phase_logs[i],
                                          start + cycle_s * i / len(logs), cycle_s) for i in range(len(logs))))
        return time.perf_counter() - start

    # Warm-up, not measured (its assignments and submissions are verified with the rest): the server's
    # connection pools fill and PostgreSQL prepares the statements, as in a server that has been running.
    await phase(warmup_logs, warmup_s)
    meter.start()
    own = time.process_time()
    elapsed = await phase(logs, seconds)
    client_cpu.append(time.process_time() - own)
    meter.stop()
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
