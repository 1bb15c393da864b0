"""The annotate queue's rule after a skip or a failed fit (models.flags): the sample goes to someone else, not
back to the person who passed on it or whose submission's fit failed on it. Only models imported: the lease
statements (lease_statement, queues) read it."""

from __future__ import annotations

from typing import Any

from sqlalchemy import exists, or_

from backend.models.enums import FlagKind
from backend.models.flags import AnnotationFlag

_FLAGS = AnnotationFlag.__table__
PASSED = (FlagKind.skip.value, FlagKind.fit_failed.value)  # after these a person is not given the sample again


def passed_over(sample_id: Any, user_id: Any) -> Any:
    """SQL condition: `user_id` neither skipped `sample_id` nor had a fit fail on it."""
    f = _FLAGS.c
    # Plain binds, not an expanding IN: the lease is one statement prepared once (psycopg), whose parameters are
    # rendered once (tests/backend/services/test_queue_head_plan.py runs it as such).
    return ~exists().where(f.sample_id == sample_id, f.user_id == user_id, or_(*(f.kind == kind for kind in PASSED)))
