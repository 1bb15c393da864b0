"""clicks without their redundant foreign keys to samples and users

Issue 17 (API capacity): PostgreSQL checks a foreign key once per inserted row, so a 48-click submission ran
192 referential checks, about half of its statement's time (EXPLAIN ANALYZE). Two of the four are redundant:
a click's sample and user are its submission's (the one statement that writes them copies both), and the
submission's own foreign keys already hold both (`submissions.sample_id` cascades on delete, and clicks go
with their submission through `clicks.submission_id`). The keys to the submission and to the view stay.

Revision ID: 0008_api_capacity2
Revises: 0007
Create Date: 2026-12-03 08:15:00
"""

from __future__ import annotations

from collections.abc import Sequence

from alembic import op

revision: str = '0008_api_capacity2'
down_revision: str | None = '0007'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('clicks', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('fk_clicks_sample_id_samples'), type_='foreignkey')
        batch_op.drop_constraint(batch_op.f('fk_clicks_user_id_users'), type_='foreignkey')


def downgrade() -> None:
    with op.batch_alter_table('clicks', schema=None) as batch_op:
        batch_op.create_foreign_key(batch_op.f('fk_clicks_user_id_users'), 'users', ['user_id'], ['id'])
        batch_op.create_foreign_key(batch_op.f('fk_clicks_sample_id_samples'), 'samples', ['sample_id'], ['id'],
                                    ondelete='CASCADE')
