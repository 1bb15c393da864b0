"""annotation flags: no hand, skip, failed fits

Issue 38: "no hand here" (per view and per sample) and "skip" as actions with a reason, and the fits that
failed on an annotator's submission, one row each; the annotate queue passes over a sample for a person who
skipped it or whose submission's fit failed on it (it goes to someone else, not back to them in a loop).

Revision ID: 0010_annotation_flags
Revises: 0009_review_queue
Create Date: 2026-12-06 04:30:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0010_annotation_flags'
down_revision: str | None = '0009_review_queue'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('annotation_flags',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('sample_id', sa.Integer(), nullable=False),
    sa.Column('view_id', sa.Integer(), nullable=True),
    sa.Column('user_id', sa.Integer(), nullable=True),
    sa.Column('submission_id', sa.Integer(), nullable=True),
    sa.Column('kind', sa.String(length=20), nullable=False),
    sa.Column('reason', sa.String(length=2000), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.CheckConstraint("kind IN ('no_hand_view', 'no_hand', 'skip', 'fit_failed')",
                       name=op.f('ck_annotation_flags_kind_valid')),
    sa.ForeignKeyConstraint(['sample_id'], ['samples.id'], name=op.f('fk_annotation_flags_sample_id_samples'),
                            ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['view_id'], ['views.id'], name=op.f('fk_annotation_flags_view_id_views'),
                            ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['user_id'], ['users.id'], name=op.f('fk_annotation_flags_user_id_users'),
                            ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['submission_id'], ['submissions.id'],
                            name=op.f('fk_annotation_flags_submission_id_submissions'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_annotation_flags'))
    )
    with op.batch_alter_table('annotation_flags', schema=None) as batch_op:
        batch_op.create_index('ix_annotation_flags_sample_user', ['sample_id', 'user_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_annotation_flags_user_id'), ['user_id'], unique=False)


def downgrade() -> None:
    with op.batch_alter_table('annotation_flags', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_annotation_flags_user_id'))
        batch_op.drop_index('ix_annotation_flags_sample_user')
    op.drop_table('annotation_flags')
