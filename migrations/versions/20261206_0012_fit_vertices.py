"""fit vertices

The fitted mesh stored with the fit (issue 39): the worker had the vertices, so the API shows them rather than
posing the hand again from the parameters. Little-endian float32 (V, 3), metres, world frame; NULL for fits
recorded before this revision (the API poses those from their parameters).

Revision ID: 0012_fit_vertices
Revises: 0011_guidelines
Create Date: 2026-12-06 07:45:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0012_fit_vertices'
down_revision: str | None = '0011_guidelines'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('fits') as batch:
        batch.add_column(sa.Column('vertices_f32', sa.LargeBinary(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('fits') as batch:
        batch.drop_column('vertices_f32')
