"""preannotate job kind

Round 0 without clicks (issue 15): a 'preannotate' job runs the pretrained detector, the triangulation
and a fit on a project's unlabeled samples. Only the CHECK constraint of jobs.kind changes.

Revision ID: 0005
Revises: 0004
Create Date: 2026-12-02 07:30:00
"""

from __future__ import annotations

from collections.abc import Sequence

from alembic import op

revision: str = '0005'
down_revision: str | None = '0004'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

KINDS_BEFORE = ('fit', 'predict', 'train', 'round', 'import_capture', 'export')
KINDS_AFTER = (*KINDS_BEFORE, 'preannotate')


def _kind_check(kinds: tuple[str, ...]) -> str:
    return "kind IN (" + ", ".join(f"'{k}'" for k in kinds) + ")"


def upgrade() -> None:
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_jobs_kind_valid'), type_='check')
        batch_op.create_check_constraint(batch_op.f('ck_jobs_kind_valid'), _kind_check(KINDS_AFTER))


def downgrade() -> None:
    # Jobs of the new kind cannot satisfy the old constraint: they go first (their samples keep their fits).
    op.execute("DELETE FROM jobs WHERE kind = 'preannotate'")
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_jobs_kind_valid'), type_='check')
        batch_op.create_check_constraint(batch_op.f('ck_jobs_kind_valid'), _kind_check(KINDS_BEFORE))
