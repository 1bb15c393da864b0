"""jobs.worker_process

The operating-system process of a job's current attempt (backend.broker.worker_processes), so that a claimant on
the same machine takes over a job whose process is gone without waiting for its heartbeat to grow old.

Revision ID: 0003
Revises: 0002
Create Date: 2026-12-02 07:40:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0003'
down_revision: str | None = '0002'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.add_column(sa.Column('worker_process', sa.String(length=120), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_column('worker_process')
