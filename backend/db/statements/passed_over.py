"""The annotate queue's rule after a skip or a failed fit (models.flags): the sample goes to someone else, not
back to the person who passed on it or whose submission's fit failed on it. Only models imported: the lease
statements (lease_statement, queues) read it."""

from __future__ import annotations

from typing import Any

from sqlalchemy import exists, literal_column

from backend.models.enums import FlagKind
from backend.models.flags import AnnotationFlag

_FLAGS = AnnotationFlag.__table__
PASSED = (FlagKind.skip.value, FlagKind.fit_failed.value,  # after these a person is not given the sample again
          FlagKind.agreement.value)  # (agreement: they made its first look; services.review.agreement)


def passed_over(sample_id: Any, user_id: Any) -> Any:
    """SQL condition: `user_id` neither skipped `sample_id` nor had a fit fail on it."""
    f = _FLAGS.c
    # SQL constants, not an expanding IN nor binds: the lease is one statement prepared once (psycopg), its text
    # under psycopg's 4096-byte cache limit (tests/backend/db/statements/test_lease_statement_size.py) and its
    # parameters rendered once (test_queue_head_plan.py); the kinds are the enum's own values, never user input.
    return ~exists().where(f.sample_id == sample_id, f.user_id == user_id,
                           f.kind.in_([literal_column(f"'{kind}'") for kind in PASSED]))
