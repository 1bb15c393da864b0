"""sequence hand side, project working width

Left hands per sequence (issue 18): sequences.side, 'right' or 'left', read from the capture at import;
the fit loads that side's hand model. Rows from before the column are right hands (the server default),
as every fit so far used the right model. And projects.working_width_px (capture format v2's
working_width_px, NULL for earlier imports): the width views are shown at, derived from the originals.

Revision ID: 0007
Revises: 0006
Create Date: 2026-12-02 14:45:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0007'
down_revision: str | None = '0006'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('projects', schema=None) as batch_op:
        batch_op.add_column(sa.Column('working_width_px', sa.Integer(), nullable=True))
    with op.batch_alter_table('sequences', schema=None) as batch_op:
        batch_op.add_column(sa.Column('side', sa.String(length=10), server_default='right', nullable=False))
        batch_op.create_check_constraint(batch_op.f('ck_sequences_side_valid'), "side IN ('right', 'left')")


def downgrade() -> None:
    with op.batch_alter_table('sequences', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_sequences_side_valid'), type_='check')
        batch_op.drop_column('side')
    with op.batch_alter_table('projects', schema=None) as batch_op:
        batch_op.drop_column('working_width_px')
