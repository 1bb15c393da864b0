"""the review queue's index (PostgreSQL)

Issue 17 (API capacity): a reviewer's lease takes the first free sample in review by confidence (descending, NULLs
last), then id. Without an index in that order PostgreSQL sorted every sample in review on each lease (20,000 in
review, as after pre-annotating a large capture: 5-9 ms a lease); with it the lease reads the queue's head. SQLite
refuses NULLS LAST in an index, and an embedded project's queue is small: PostgreSQL only, as in the model
(`ddl_if`).

Revision ID: 0009_review_queue
Revises: 0008_api_capacity2
Create Date: 2026-12-04 22:40:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0009_review_queue'
down_revision: str | None = '0008_api_capacity2'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    if op.get_bind().dialect.name == 'postgresql':
        op.create_index('ix_samples_review_queue', 'samples',
                        ['state', sa.text('confidence DESC NULLS LAST'), 'id'], unique=False)


def downgrade() -> None:
    if op.get_bind().dialect.name == 'postgresql':
        op.drop_index('ix_samples_review_queue', table_name='samples')
