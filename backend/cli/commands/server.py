"""`handloop serve`, `handloop import DIR`, `handloop users ...`, `handloop db upgrade|downgrade|current`."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import typer

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

        from backend.db.migrate import upgrade
        from backend.settings import get_settings

        settings = get_settings()
        if migrate:
            settings.data_dir.mkdir(parents=True, exist_ok=True)
            upgrade(settings.resolved_database_url)
        uvicorn.run("backend.app:create_app", factory=True, host=host, port=port, workers=workers,
                    log_level="info")

    @app.command("import")
    def import_(path: Path = typer.Argument(..., help="Capture directory."),
                project: str | None = typer.Option(None, help="Project name (default: the capture's name)."),
                queue: bool = typer.Option(True, help="Queue every sample for annotation (round 0).")) -> None:
        """Validate a capture, verify every file in full, and import it as a project (nothing if a file is broken);
        with HANDLOOP_PREANNOTATE_ON_IMPORT, then queue its pre-annotation by the pretrained detector."""
        from tqdm import tqdm

        from backend.broker.celery_queue import CeleryJobQueue
        from backend.db.session import create_engine_from_url, make_session_factory
        from backend.services import preannotation
        from backend.services.errors import DomainError
        from backend.services.storage import LocalDiskStorage
        from backend.services.transactions import run_after_commit
        from backend.settings import get_settings

        settings = get_settings()
        factory = make_session_factory(create_engine_from_url(settings.resolved_database_url))
        bar = tqdm(unit="file", desc="verifying", file=sys.stderr)

        def verified(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)
            if done == total:
                bar.close()

        try:
            with factory() as session:
                result = preannotation.import_capture(
                    session, LocalDiskStorage(settings.storage_dir), CeleryJobQueue(settings), path,
                    enabled=settings.preannotate_on_import, project_name=project, queue_for_annotation=queue,
                    actor_id=None, progress=verified)
                session.commit()
                run_after_commit(session)  # the pre-annotation job's task, once its row is committed
        except DomainError as exc:
            bar.close()
            logger.error("%s", exc.message)
            raise typer.Exit(code=2) from exc
        bar.close()
        typer.echo(result.model_dump_json())

    @users.command("create")
    def create_user(email: str = typer.Argument(...),
                    role: str = typer.Option("annotator", help="annotator, reviewer or admin"),
                    full_name: str = typer.Option(""),
                    password: str = typer.Option(..., prompt=True, hide_input=True, confirmation_prompt=True,
                                                 envvar="HANDLOOP_NEW_USER_PASSWORD")) -> None:
        """Create an account (the first admin is made this way)."""
        from backend.db.session import create_engine_from_url, make_session_factory
        from backend.models.enums import Role
        from backend.services.errors import DomainError
        from backend.services.users import create_user as create
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
        from backend.db.migrate import upgrade
        from backend.settings import get_settings

        settings = get_settings()
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        upgrade(settings.resolved_database_url, revision)

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
