"""job dispatch and idempotent results

The outbox of the job hand-off (jobs.dispatched_at), attempts and worker of each job, and unique
constraints that make a redelivered task unable to record a fit or a prediction twice.

Revision ID: 0002
Revises: 0001
Create Date: 2026-12-01 19:11:19.583710
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0002'
down_revision: str | None = '0001'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('fits', schema=None) as batch_op:
        batch_op.create_unique_constraint(batch_op.f('uq_fits_job_id'), ['job_id'])

    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.add_column(sa.Column('dispatched_at', sa.DateTime(timezone=True), nullable=True))
        batch_op.add_column(sa.Column('attempts', sa.Integer(), server_default='0', nullable=False))
        batch_op.add_column(sa.Column('worker', sa.String(length=200), nullable=True))

    with op.batch_alter_table('predictions', schema=None) as batch_op:
        batch_op.create_unique_constraint(batch_op.f('uq_predictions_job_id'), ['job_id', 'sample_id'])


def downgrade() -> None:
    with op.batch_alter_table('predictions', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('uq_predictions_job_id'), type_='unique')

    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_column('worker')
        batch_op.drop_column('attempts')
        batch_op.drop_column('dispatched_at')

    with op.batch_alter_table('fits', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('uq_fits_job_id'), type_='unique')
