"""agreement: samples annotated twice, blind, by two annotators

Issue 40: `agreement_pairs` (one row per picked sample: both looks' submissions and fits, the 2D and 3D
disagreement, the fit that became the label), `quality_settings.agreement_share` (0 for rows from before the
setting: off until the admin sets it) and the annotation flag kind 'agreement' (the first look's annotator, whom the
annotate queue no longer gives the sample).

Revision ID: 0014_agreement
Revises: 0013_quality
Create Date: 2026-12-06 08:40:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0014_agreement'
down_revision: str | None = '0013_quality'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_KINDS_BEFORE = "kind IN ('no_hand_view', 'no_hand', 'skip', 'fit_failed')"
_KINDS_AFTER = "kind IN ('no_hand_view', 'no_hand', 'skip', 'fit_failed', 'agreement')"


def upgrade() -> None:
    op.create_table('agreement_pairs',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('sample_id', sa.Integer(), nullable=False),
    sa.Column('state', sa.String(length=20), nullable=False),
    sa.Column('first_user_id', sa.Integer(), nullable=True),
    sa.Column('first_submission_id', sa.Integer(), nullable=True),
    sa.Column('first_fit_id', sa.Integer(), nullable=True),
    sa.Column('second_user_id', sa.Integer(), nullable=True),
    sa.Column('second_submission_id', sa.Integer(), nullable=True),
    sa.Column('second_fit_id', sa.Integer(), nullable=True),
    sa.Column('disagreement_px', sa.JSON(), nullable=True),
    sa.Column('mean_px', sa.Double(), nullable=True),
    sa.Column('disagreement_mm', sa.Double(), nullable=True),
    sa.Column('label_fit_id', sa.Integer(), nullable=True),
    sa.Column('disputed', sa.Boolean(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('decided_at', sa.DateTime(timezone=True), nullable=True),
    sa.CheckConstraint("state IN ('second_look', 'done')", name=op.f('ck_agreement_pairs_state_valid')),
    sa.ForeignKeyConstraint(['sample_id'], ['samples.id'], name=op.f('fk_agreement_pairs_sample_id_samples'),
                            ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['first_user_id'], ['users.id'], name=op.f('fk_agreement_pairs_first_user_id_users'),
                            ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['first_submission_id'], ['submissions.id'],
                            name=op.f('fk_agreement_pairs_first_submission_id_submissions'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['first_fit_id'], ['fits.id'], name=op.f('fk_agreement_pairs_first_fit_id_fits'),
                            ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['second_user_id'], ['users.id'], name=op.f('fk_agreement_pairs_second_user_id_users'),
                            ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['second_submission_id'], ['submissions.id'],
                            name=op.f('fk_agreement_pairs_second_submission_id_submissions'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['second_fit_id'], ['fits.id'], name=op.f('fk_agreement_pairs_second_fit_id_fits'),
                            ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['label_fit_id'], ['fits.id'], name=op.f('fk_agreement_pairs_label_fit_id_fits'),
                            ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_agreement_pairs')),
    sa.UniqueConstraint('sample_id', name=op.f('uq_agreement_pairs_sample_id'))
    )
    with op.batch_alter_table('quality_settings', schema=None) as batch_op:
        batch_op.add_column(sa.Column('agreement_share', sa.Double(), server_default='0', nullable=False))
        batch_op.create_check_constraint(op.f('ck_quality_settings_agreement_share_range'),
                                         'agreement_share >= 0 AND agreement_share <= 1')
    with op.batch_alter_table('annotation_flags', schema=None) as batch_op:
        batch_op.drop_constraint(op.f('ck_annotation_flags_kind_valid'), type_='check')
        batch_op.create_check_constraint(op.f('ck_annotation_flags_kind_valid'), _KINDS_AFTER)


def downgrade() -> None:
    op.execute("DELETE FROM annotation_flags WHERE kind = 'agreement'")
    with op.batch_alter_table('annotation_flags', schema=None) as batch_op:
        batch_op.drop_constraint(op.f('ck_annotation_flags_kind_valid'), type_='check')
        batch_op.create_check_constraint(op.f('ck_annotation_flags_kind_valid'), _KINDS_BEFORE)
    with op.batch_alter_table('quality_settings', schema=None) as batch_op:
        batch_op.drop_constraint(op.f('ck_quality_settings_agreement_share_range'), type_='check')
        batch_op.drop_column('agreement_share')
    op.drop_table('agreement_pairs')
