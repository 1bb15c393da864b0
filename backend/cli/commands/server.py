"""`handloop serve`, `handloop import DIR`, `handloop users ...`, `handloop db upgrade|downgrade|current`."""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import typer

if TYPE_CHECKING:
    from sqlalchemy.orm import Session

    from backend.settings import Settings

logger = logging.getLogger("handloop.server")


def register(app: typer.Typer, bench: typer.Typer) -> None:
    db = typer.Typer(help="Database migrations (Alembic; URL from HANDLOOP_DATABASE_URL).", no_args_is_help=True)
    users = typer.Typer(help="Manage user accounts.", no_args_is_help=True)
    app.add_typer(db, name="db")
    app.add_typer(users, name="users")

    @app.command("serve")
    def serve(host: str = typer.Option("127.0.0.1", help="Interface to bind (loopback by default)."),
              port: int = typer.Option(8000, min=1, max=65535),
              workers: int = typer.Option(1, min=1, max=64, help="uvicorn worker processes."),
              migrate: bool = typer.Option(True, help="Upgrade the database to the newest schema first.")) -> None:
        """Run the API server (OpenAPI docs at /docs)."""
        import uvicorn

        from backend.settings import get_settings

        settings = get_settings()
        if migrate:
            _migrate(settings)
        # proxy_headers=False: uvicorn would take X-Forwarded-For from any localhost peer; the app trusts only
        # HANDLOOP_TRUSTED_PROXIES (backend.app).
        uvicorn.run("backend.app:create_app", factory=True, host=host, port=port, workers=workers, proxy_headers=False,
                    log_level="info")

    @app.command("import")
    def import_(path: Path = typer.Argument(..., help="Capture directory."),
                project: str | None = typer.Option(None, help="Project name (default: the capture's name)."),
                queue: bool = typer.Option(True, help="Queue every sample for annotation (round 0); with "
                                                      "pre-annotation, those the reviewers' queue does not take."),
                preannotate: bool | None = typer.Option(
                    None, "--preannotate/--no-preannotate", show_default=False,
                    help="Import the samples unlabeled and queue their pre-annotation by the pretrained detector "
                         "(round 0 without clicks; a worker runs it). Default: on where the detector is installed."),
                wait: bool = typer.Option(False, "--wait", help="Follow the pre-annotation job until it ends "
                                                                "(a worker must run it: `handloop worker`)."),
                migrate: bool = typer.Option(True, help="Upgrade the database to the newest schema first "
                                                        "(as `handloop serve` does).")) -> None:
        """Validate a capture, verify every file in full, and import it as a project (nothing if a file is broken);
        then, where the detector is installed, queue its pre-annotation (round 0 without clicks)."""
        from tqdm import tqdm

        from backend.broker.celery_queue import CeleryJobQueue
        from backend.cli.job_progress import follow_job, preannotation_summary
        from backend.db.session import create_engine_from_url, make_session_factory
        from backend.services.captures.storage import LocalDiskStorage
        from backend.services.errors import DomainError
        from backend.services.rounds import preannotation
        from backend.services.transactions import run_after_commit
        from backend.settings import get_settings

        settings = get_settings()
        if migrate:
            _migrate(settings)
        enabled = preannotate
        if enabled is None:  # the default: round 0 without clicks where the detector can run
            problem = preannotation.quick_detector_problem()
            enabled = problem is None
            if problem is not None:
                where = "the annotators' queue (needs annotation)" if queue else "unlabeled"
                typer.echo(f"pre-annotation off: {problem}; the samples go to {where}", err=True)
        factory = make_session_factory(create_engine_from_url(settings.resolved_database_url))
        bar = tqdm(unit="file", desc="verifying", file=sys.stderr, delay=0.5)  # not drawn for a refusal

        def verified(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)
            if done == total:
                bar.close()

        try:
            with factory() as session:
                _require_schema(session)
                result = preannotation.import_capture(
                    session, LocalDiskStorage(settings.storage_dir), CeleryJobQueue(settings), path,
                    enabled=enabled, required=bool(preannotate), project_name=project, queue_for_annotation=queue,
                    actor_id=None, progress=verified)
                session.commit()
                run_after_commit(session)  # the pre-annotation job's task, once its row is committed
        except DomainError as exc:
            bar.close()
            logger.error("%s", exc.message)
            raise typer.Exit(code=2) from exc
        bar.close()
        job_id = result.preannotation_job_id
        if job_id is not None:
            typer.echo(f"pre-annotation: job {job_id} queued for {result.samples} samples (detector -> "
                       "triangulation -> fit; reviewers first); a worker runs it (`handloop worker`); its "
                       "progress is on the admin page" + ("" if wait else " (or follow it with --wait)"), err=True)
        elif result.preannotation:
            typer.echo(f"pre-annotation {result.preannotation}", err=True)
        typer.echo(result.model_dump_json())
        if wait and job_id is not None:
            end = follow_job(factory, job_id, label=f"pre-annotation (job {job_id})")
            if end is None or end.state != "succeeded":
                typer.echo(f"pre-annotation job {job_id} {end.state}: {end.error or ''}" if end else
                           f"stopped following pre-annotation job {job_id}; it goes on", err=True)
                raise typer.Exit(code=1)
            typer.echo(f"pre-annotation done: {preannotation_summary(end.result or {})}", err=True)

    @users.command("create")
    def create_user(email: str = typer.Argument(...),
                    role: str = typer.Option("annotator", help="annotator, reviewer or admin"),
                    full_name: str = typer.Option(""),
                    password: str = typer.Option(..., prompt=True, hide_input=True, confirmation_prompt=True,
                                                 envvar="HANDLOOP_NEW_USER_PASSWORD")) -> None:
        """Create an account (the first admin is made this way)."""
        from backend.db.session import create_engine_from_url, make_session_factory
        from backend.models.enums import Role
        from backend.services.accounts.users import create_user as create
        from backend.services.errors import DomainError
        from backend.settings import get_settings

        if role not in {r.value for r in Role}:
            raise typer.BadParameter(f"role must be annotator, reviewer or admin, not {role!r}")
        if len(password) < 8:
            raise typer.BadParameter("password needs at least 8 characters")
        factory = make_session_factory(create_engine_from_url(get_settings().resolved_database_url))
        try:
            with factory.begin() as session:
                user = create(session, email, password, Role(role), full_name)
                typer.echo(f"created user {user.id} {user.email} ({user.role})")
        except DomainError as exc:
            logger.error("%s", exc.message)
            raise typer.Exit(code=2) from exc

    @users.command("list")
    def list_users() -> None:
        from sqlalchemy import select

        from backend.db.session import create_engine_from_url, make_session_factory
        from backend.models.users import User
        from backend.settings import get_settings

        factory = make_session_factory(create_engine_from_url(get_settings().resolved_database_url))
        with factory() as session:
            for user in session.execute(select(User).order_by(User.id)).scalars():
                typer.echo(f"{user.id}\t{user.email}\t{user.role}\t{'active' if user.is_active else 'inactive'}")

    @db.command("upgrade")
    def db_upgrade(revision: str = typer.Argument("head")) -> None:
        """Upgrade the database schema."""
        from backend.settings import get_settings

        _migrate(get_settings(), revision)

    @db.command("downgrade")
    def db_downgrade(revision: str = typer.Argument(..., help="Target revision, e.g. -1 or base.")) -> None:
        """Downgrade the database schema."""
        from backend.db.migrate import downgrade
        from backend.settings import get_settings

        downgrade(get_settings().resolved_database_url, revision)

    @db.command("current")
    def db_current() -> None:
        from backend.db.migrate import current
        from backend.settings import get_settings

        typer.echo(current(get_settings().resolved_database_url) or "(empty database)")


def _migrate(settings: Settings, revision: str = "head") -> None:
    """Upgrade the database (created where it is new, with its data folder) to `revision`: `serve`, `import`
    and `db upgrade` (the demo and the simulation's stack call backend.db.migrate the same way)."""
    from backend.db.migrate import upgrade

    settings.data_dir.mkdir(parents=True, exist_ok=True)
    upgrade(settings.resolved_database_url, revision)


def _require_schema(session: Session) -> None:
    """Refuse (DomainError) a database without handloop's tables (--no-migrate on a new one)."""
    from sqlalchemy import inspect

    from backend.services.errors import InvalidInputError

    if not inspect(session.connection()).has_table("projects"):
        raise InvalidInputError("the database has no handloop tables yet: run `handloop db upgrade` first "
                                "(or import without --no-migrate)")
