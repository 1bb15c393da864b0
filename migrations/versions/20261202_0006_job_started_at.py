"""jobs.started_at, failed rounds

jobs.started_at: when the job's current attempt started (services.jobs.jobs.claim sets it at each claim), so the
jobs list can show how long the work took apart from the time the job waited in the queue. NULL for a job no
worker has started (and for jobs finished before this revision: their start was not recorded).

rounds.state 'failed' and rounds.failure: a round whose job failed, and why (services.jobs.round_failure); the round
before it is open again, as it was before the launch.

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

ROUND_STATES_BEFORE = ('running', 'completed', 'cancelled')
ROUND_STATES_AFTER = (*ROUND_STATES_BEFORE, 'failed')


def _state_check(states: tuple[str, ...]) -> str:
    return "state IN (" + ", ".join(f"'{s}'" for s in states) + ")"


def upgrade() -> None:
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.add_column(sa.Column('started_at', sa.DateTime(timezone=True), nullable=True))
    with op.batch_alter_table('rounds', schema=None) as batch_op:
        batch_op.add_column(sa.Column('failure', sa.Text(), nullable=True))
        batch_op.drop_constraint(batch_op.f('ck_rounds_state_valid'), type_='check')
        batch_op.create_check_constraint(batch_op.f('ck_rounds_state_valid'), _state_check(ROUND_STATES_AFTER))


def downgrade() -> None:
    # A failed round cannot satisfy the old constraint: it reads as cancelled (both ended without completing).
    op.execute("UPDATE rounds SET state = 'cancelled' WHERE state = 'failed'")
    with op.batch_alter_table('rounds', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_rounds_state_valid'), type_='check')
        batch_op.create_check_constraint(batch_op.f('ck_rounds_state_valid'), _state_check(ROUND_STATES_BEFORE))
        batch_op.drop_column('failure')
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_column('started_at')
