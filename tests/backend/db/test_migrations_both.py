"""The migrations upgrade and downgrade on SQLite and PostgreSQL and match the models."""

from __future__ import annotations

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import create_engine, inspect

import backend.models  # noqa: F401
from backend.db.base import Base
from backend.db.migrate import alembic_config, current, downgrade, include_for, upgrade


def _head() -> str:
    from alembic.script import ScriptDirectory

    return ScriptDirectory.from_config(alembic_config("sqlite://")).get_current_head()


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def empty_url(request, tmp_path):
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'empty.sqlite3'}"
    url = request.getfixturevalue("pg_url")
    downgrade(url, "base")  # the per-test copy of the template is migrated: start from nothing
    return url


def test_upgrade_downgrade_upgrade(empty_url):
    upgrade(empty_url)
    assert current(empty_url) == _head()
    engine = create_engine(empty_url)
    assert set(Base.metadata.tables) <= set(inspect(engine).get_table_names())
    with engine.connect() as conn:
        context = MigrationContext.configure(conn, opts={"compare_type": True,
                                                         "include_object": include_for(conn.dialect.name)})
        diff = compare_metadata(context, Base.metadata)
    assert diff == [], diff  # the migrations build exactly the models' schema
    engine.dispose()
    downgrade(empty_url, "base")
    engine = create_engine(empty_url)
    assert set(inspect(engine).get_table_names()) <= {"alembic_version"}
    engine.dispose()
    upgrade(empty_url)
    assert current(empty_url) == _head()


def _agreement_states_check(url: str) -> str:
    engine = create_engine(url)
    with engine.connect() as conn:
        if conn.dialect.name == "sqlite":
            sql = conn.exec_driver_sql("SELECT sql FROM sqlite_master WHERE name = 'agreement_pairs'").scalar_one()
        else:
            sql = conn.exec_driver_sql("SELECT pg_get_constraintdef(oid) FROM pg_constraint "
                                       "WHERE conname = 'ck_agreement_pairs_state_valid'").scalar_one()
    engine.dispose()
    return sql


def test_0015_lets_an_agreement_pair_end_single_and_back(empty_url):
    upgrade(empty_url, "0014_agreement")
    assert "'single'" not in _agreement_states_check(empty_url)
    upgrade(empty_url)
    assert "'single'" in _agreement_states_check(empty_url)
    downgrade(empty_url, "0014_agreement")
    assert "'single'" not in _agreement_states_check(empty_url) and "'done'" in _agreement_states_check(empty_url)
