"""The one-statement lease of PostgreSQL stays under psycopg's query cache limit (its text is parsed again on
every execution beyond 4096 bytes; backend/db/statements/lease_statement.py)."""

from __future__ import annotations

import pytest
from sqlalchemy.dialects import postgresql

from backend.db.statements.lease_statement import acquire_statement
from backend.models.enums import LeaseKind


@pytest.mark.parametrize("kind", list(LeaseKind), ids=lambda k: k.value)
def test_the_lease_statement_fits_psycopgs_query_cache(kind):
    text = str(acquire_statement(kind).compile(dialect=postgresql.psycopg.dialect()))
    assert "sequences.side" in text and len(text.encode()) < 4096, len(text.encode())
