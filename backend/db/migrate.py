"""Run the Alembic migrations from code (CLI, tests, benchmarks) against any URL."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from sqlalchemy import create_engine

ALEMBIC_INI = Path(__file__).resolve().parents[2] / "alembic.ini"


def alembic_config(url: str) -> Config:
    config = Config(str(ALEMBIC_INI))
    config.attributes["url"] = url
    config.attributes["configure_logging"] = False  # keep the caller's logging setup
    return config


def upgrade(url: str, revision: str = "head") -> None:
    command.upgrade(alembic_config(url), revision)


def downgrade(url: str, revision: str = "base") -> None:
    command.downgrade(alembic_config(url), revision)


def current(url: str) -> str | None:
    engine = create_engine(url)
    try:
        with engine.connect() as connection:
            return MigrationContext.configure(connection).get_current_revision()
    finally:
        engine.dispose()


def include_for(dialect: str) -> Callable[..., bool]:
    """Alembic's `include_object` for a database of `dialect`: a model's index that only another dialect creates
    (`Index(...).ddl_if(dialect=...)`, which autogenerate does not read; SQLAlchemy keeps it as `_ddl_if`) is left
    out of the comparison with the models."""

    def include(obj: Any, _name: str | None, type_: str, reflected: bool, _compare_to: Any) -> bool:
        only = getattr(getattr(obj, "_ddl_if", None), "dialect", None)
        return type_ != "index" or reflected or only is None or only == dialect

    return include
