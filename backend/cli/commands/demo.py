"""`handloop demo`: everything a first look needs, on this machine, with nothing else installed.

Synthesises a small capture (once), draws a preview, migrates the embedded SQLite database, imports the
capture as a project, makes an admin account (once; the password is kept in the data folder so a
second run can print it again), then serves the app: the API with the UI and a real Celery worker
process on the embedded broker (kombu's filesystem transport; backend.runtime.start_stack), until Ctrl-C.
Where the pretrained detector is installed the import queues round 0's pre-annotation (the product's own
path: the first sample to annotate shows the detector's proposals) and the demo shows the worker's progress.
"""

from __future__ import annotations

import logging
import secrets
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import typer

if TYPE_CHECKING:
    from backend.settings import Settings

log = logging.getLogger("handloop.demo")

DEMO_PROJECT = "demo"
DEMO_ADMIN = "admin@handloop.local"


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @app.command("demo")
    def demo(
        sequences: int = typer.Option(4, min=1, max=64, help="Sequences in the demo capture."),
        frames: int = typer.Option(12, min=1, max=1000, help="Frames per sequence."),
        width: int | None = typer.Option(None, min=32, max=4096, help="Image width (default: settings)."),
        serve: bool = typer.Option(True, help="Start the API server at the end."),
        host: str = typer.Option("127.0.0.1", help="Interface to bind (loopback by default)."),
        port: int = typer.Option(8000, min=1, max=65535),
        preannotate: bool | None = typer.Option(
            None, "--preannotate/--no-preannotate", show_default=False,
            help="Pre-annotate the imported capture with the pretrained detector (round 0 without clicks). "
                 "Default: on where the detector is installed."),
    ) -> None:
        """Set up a demo: synthetic capture, preview, database, import (pre-annotated where the detector is
        installed), admin login; then serve, showing the pre-annotation's progress."""
        from backend.services.rounds.preannotation import quick_detector_problem
        from backend.settings import get_settings

        settings = get_settings()
        problem = quick_detector_problem() if preannotate is None else None
        if problem is not None:
            typer.echo(f"  pre-annotation off: {problem}; the demo's samples go straight to the annotators")
        data_dir = settings.data_dir.resolve()
        data_dir.mkdir(parents=True, exist_ok=True)
        capture_dir = data_dir / "demo-capture"
        _ensure_capture(capture_dir, sequences, frames, width or settings.render_width_px, settings.mano_path)
        preview = data_dir / "demo-preview.png"
        _write_preview(capture_dir, preview)
        password, note = _ensure_database(capture_dir, data_dir, preannotate=preannotate is not False and not problem)
        notice = _hand_model_notice(settings.mano_path)
        typer.echo("")
        typer.echo(f"  capture : {capture_dir}")
        typer.echo(f"  preview : {preview}")
        typer.echo(f"  database: {settings.resolved_database_url}")
        typer.echo(f"  login   : {DEMO_ADMIN} / {password}")
        typer.echo(f"  model   : {notice}")
        if note:
            typer.echo(f"  round 0 : {note}")
        if serve:
            _serve(settings, host, port)


def _serve(settings: Settings, host: str, port: int) -> None:
    """The API and an embedded worker until Ctrl-C (or SIGTERM)."""

    from backend.runtime import start_stack

    mode = "embedded broker" if not settings.broker_url else f"broker {settings.broker_url.split('@')[-1]}"
    typer.echo(f"  starting: API and worker ({mode}; logs in {settings.data_dir.resolve() / 'logs'}) ...")
    stack = start_stack(settings, host=host, port=port)
    stopping = threading.Event()
    # Ctrl-C stops by the same path as SIGTERM. Python keeps SIGINT ignored when the process started with it
    # ignored (a background job of a non-interactive shell), and Ctrl-C would then do nothing.
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stopping.set())

    def stopped(seconds: float) -> bool:
        """Wait; True once Ctrl-C came or the API or the worker exited."""
        if stopping.wait(seconds):
            return True
        for name, process in (("API", stack.api), ("worker", stack.worker)):
            if process is not None and process.poll() is not None:
                log.error("the %s exited (code %s); see %s", name, process.returncode, stack.log_dir)
                stopping.set()
        return stopping.is_set()

    try:
        typer.echo(f"  URL     : {stack.base_url}/  (API docs: {stack.base_url}/docs)")
        sys.stdout.flush()
        _follow_preannotation(settings, stopped)
        typer.echo("  running : API + worker; Ctrl-C stops both")
        typer.echo("", nl=True)
        sys.stdout.flush()
        while not stopped(1.0):
            pass
    finally:
        typer.echo("  stopping ...")
        stack.stop()


def _follow_preannotation(settings: Settings, stopped: Callable[[float], bool]) -> None:
    """The demo project's pre-annotation, while one is queued or running: its progress until it ends."""
    from sqlalchemy import select

    from backend.cli.job_progress import follow_job, preannotation_summary
    from backend.db.session import create_engine_from_url, make_session_factory
    from backend.models.capture import Project
    from backend.services.rounds.preannotation import running_job

    engine = create_engine_from_url(settings.resolved_database_url)
    try:
        factory = make_session_factory(engine)
        with factory() as session:
            project_id = session.execute(select(Project.id).where(Project.name == DEMO_PROJECT)).scalar()
            job = running_job(session, project_id) if project_id is not None else None
            job_id = job.id if job is not None else None
        if job_id is None:
            return
        typer.echo(f"  round 0 : the worker pre-annotates the demo capture (job {job_id}; the admin page shows it "
                   "too); the samples reach the annotators and reviewers when it ends")
        sys.stdout.flush()
        end = follow_job(factory, job_id, label="  pre-annotating", wait=stopped)
        if end is not None:
            outcome = preannotation_summary(end.result or {}) if end.state == "succeeded" else end.error
            typer.echo(f"  round 0 : pre-annotation {end.state}: {outcome}")
    finally:
        engine.dispose()


def _ensure_capture(capture_dir: Path, sequences: int, frames: int, width: int, mano_path: Path | None) -> None:
    """Synthesise the demo capture unless a valid one is already there."""
    from tqdm import tqdm

    from workers.capture import CaptureError, read_capture
    from workers.synth.generator import generate_capture
    from workers.synth.plan import SynthConfig

    if capture_dir.exists():
        try:
            read_capture(capture_dir, check_images=False)
            log.info("reusing the demo capture in %s", capture_dir)
            return
        except CaptureError as exc:
            log.warning("re-creating the demo capture: %s", exc)
    config = SynthConfig(num_sequences=sequences, frames_per_sequence=frames, seed=0, width_px=width)
    with tqdm(total=sequences * frames, unit="frame", desc="synthesising", file=sys.stderr) as bar:
        generate_capture(capture_dir, config, force=True, mano_path=mano_path, progress=bar.update)


def _write_preview(capture_dir: Path, out: Path) -> None:
    import cv2

    from workers.capture import read_capture
    from workers.capture.preview import preview_frame

    capture = read_capture(capture_dir, check_images=False)
    grid = preview_frame(capture, capture.sequences[0].frames[0])
    cv2.imwrite(str(out), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))


def _ensure_database(capture_dir: Path, data_dir: Path, *, preannotate: bool) -> tuple[str, str | None]:
    """Migrate, import the capture as project 'demo' (queueing its pre-annotation with `preannotate`) and make
    the admin; return the admin's password and what became of the pre-annotation (None: no import now)."""
    from sqlalchemy import select

    from backend.broker.celery_queue import CeleryJobQueue
    from backend.db.migrate import upgrade
    from backend.db.session import create_engine_from_url, make_session_factory
    from backend.models.capture import Project
    from backend.models.enums import Role
    from backend.models.users import User
    from backend.services.accounts.users import create_user
    from backend.services.captures.storage import LocalDiskStorage
    from backend.services.rounds import preannotation
    from backend.services.transactions import run_after_commit
    from backend.settings import get_settings

    settings = get_settings()
    upgrade(settings.resolved_database_url)
    engine = create_engine_from_url(settings.resolved_database_url)
    password_file = data_dir / "demo-admin-password.txt"
    note = None
    try:
        with make_session_factory(engine)() as session:
            if session.execute(select(Project.id).where(Project.name == DEMO_PROJECT)).first() is None:
                result = preannotation.import_capture(
                    session, LocalDiskStorage(settings.storage_dir), CeleryJobQueue(settings), capture_dir,
                    enabled=preannotate, project_name=DEMO_PROJECT, queue_for_annotation=True, actor_id=None)
                log.info("imported the demo capture: %s", result.model_dump_json())
                note = result.preannotation
            if session.execute(select(User.id).where(User.email == DEMO_ADMIN)).first() is None:
                password = secrets.token_urlsafe(12)
                create_user(session, DEMO_ADMIN, password, Role.admin, "Demo admin")
                password_file.write_text(password + "\n")
                password_file.chmod(0o600)
            session.commit()
            run_after_commit(session)  # the pre-annotation job's task, once its row is committed
    finally:
        engine.dispose()
    if not password_file.exists():
        return "(set before; reset it with `handloop users`)", note
    return password_file.read_text().strip(), note


def _hand_model_notice(mano_path: Path | None) -> str:
    from workers.handmodel.loading import STAND_IN_NOTICE

    return f"MANO from {mano_path}" if mano_path else STAND_IN_NOTICE
