"""jobs.started_at

When the job's current attempt started (services.jobs.claim sets it at each claim), so the jobs list can show
how long the work took apart from the time the job waited in the queue. NULL for a job no worker has started
(and for jobs finished before this revision: their start was not recorded).

Revision ID: 0006
Revises: 0005
Create Date: 2026-12-02 14:45:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0006'
down_revision: str | None = '0005'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.add_column(sa.Column('started_at', sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_column('started_at')
