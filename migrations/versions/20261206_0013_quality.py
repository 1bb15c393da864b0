"""label quality: blind audits of accepted labels and the quality settings

Issue 40: `label_audits` (one row per audit of an accepted label: its sample, fit, round and stream, the verdict
and who gave it) and `quality_settings` (the audit share, its seed, the precision target; one row); `rounds.heuristic_thresholds`
(the thresholds chosen for the round and why); `gold_labels` (accepted labels an admin marked gold).

Revision ID: 0013_quality
Revises: 0012_fit_vertices
Create Date: 2026-12-06 07:30:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0013_quality'
down_revision: str | None = '0012_fit_vertices'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('label_audits',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('sample_id', sa.Integer(), nullable=False),
    sa.Column('fit_id', sa.Integer(), nullable=True),
    sa.Column('round_id', sa.Integer(), nullable=True),
    sa.Column('stream', sa.String(length=20), nullable=False),
    sa.Column('kind', sa.String(length=10), server_default='audit', nullable=False),
    sa.Column('accepted_by_id', sa.Integer(), nullable=True),
    sa.Column('state', sa.String(length=20), nullable=False),
    sa.Column('verdict', sa.String(length=20), nullable=True),
    sa.Column('auditor_id', sa.Integer(), nullable=True),
    sa.Column('decision_id', sa.Integer(), nullable=True),
    sa.Column('reason', sa.Text(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('decided_at', sa.DateTime(timezone=True), nullable=True),
    sa.CheckConstraint("stream IN ('heuristic', 'manual', 'annotated')", name=op.f('ck_label_audits_stream_valid')),
    sa.CheckConstraint("state IN ('pending', 'done', 'void')", name=op.f('ck_label_audits_state_valid')),
    sa.CheckConstraint("verdict IS NULL OR verdict IN ('correct', 'wrong')",
                       name=op.f('ck_label_audits_verdict_valid')),
    sa.CheckConstraint("kind IN ('audit', 'gold')", name=op.f('ck_label_audits_kind_valid')),
    sa.ForeignKeyConstraint(['sample_id'], ['samples.id'], name=op.f('fk_label_audits_sample_id_samples'),
                            ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['fit_id'], ['fits.id'], name=op.f('fk_label_audits_fit_id_fits'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['round_id'], ['rounds.id'], name=op.f('fk_label_audits_round_id_rounds'),
                            ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['accepted_by_id'], ['users.id'], name=op.f('fk_label_audits_accepted_by_id_users'),
                            ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['auditor_id'], ['users.id'], name=op.f('fk_label_audits_auditor_id_users'),
                            ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['decision_id'], ['decisions.id'], name=op.f('fk_label_audits_decision_id_decisions'),
                            ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_label_audits'))
    )
    with op.batch_alter_table('label_audits', schema=None) as batch_op:
        batch_op.create_index('ix_label_audits_state', ['state', 'id'], unique=False)
        batch_op.create_index(batch_op.f('ix_label_audits_sample_id'), ['sample_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_label_audits_round_id'), ['round_id'], unique=False)
    with op.batch_alter_table('rounds', schema=None) as batch_op:
        batch_op.add_column(sa.Column('heuristic_thresholds', sa.JSON(), nullable=True))
    op.create_table('quality_settings',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('audit_share', sa.Double(), nullable=False),
    sa.Column('audit_seed', sa.Integer(), nullable=False),
    sa.Column('precision_target', sa.Double(), nullable=True),
    sa.Column('min_audits_for_target', sa.Integer(), nullable=False),
    sa.Column('auditor_error_rate', sa.Double(), nullable=False),
    sa.Column('gold_share', sa.Double(), nullable=False),
    sa.Column('updated_by_id', sa.Integer(), nullable=True),
    sa.Column('updated_at', sa.DateTime(timezone=True), nullable=False),
    sa.CheckConstraint('audit_share >= 0 AND audit_share <= 1', name=op.f('ck_quality_settings_audit_share_range')),
    sa.CheckConstraint('precision_target IS NULL OR (precision_target > 0 AND precision_target < 1)',
                       name=op.f('ck_quality_settings_precision_target_range')),
    sa.CheckConstraint('auditor_error_rate >= 0 AND auditor_error_rate < 0.5',
                       name=op.f('ck_quality_settings_auditor_error_rate_range')),
    sa.CheckConstraint('gold_share >= 0 AND gold_share <= 1', name=op.f('ck_quality_settings_gold_share_range')),
    sa.ForeignKeyConstraint(['updated_by_id'], ['users.id'], name=op.f('fk_quality_settings_updated_by_id_users'),
                            ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_quality_settings'))
    )
    op.create_table('gold_labels',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('sample_id', sa.Integer(), nullable=False),
    sa.Column('fit_id', sa.Integer(), nullable=True),
    sa.Column('stream', sa.String(length=20), nullable=False),
    sa.Column('marked_by_id', sa.Integer(), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['sample_id'], ['samples.id'], name=op.f('fk_gold_labels_sample_id_samples'),
                            ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['fit_id'], ['fits.id'], name=op.f('fk_gold_labels_fit_id_fits'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['marked_by_id'], ['users.id'], name=op.f('fk_gold_labels_marked_by_id_users'),
                            ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_gold_labels')),
    sa.UniqueConstraint('sample_id', name=op.f('uq_gold_labels_sample_id'))
    )


def downgrade() -> None:
    op.drop_table('gold_labels')
    op.drop_table('quality_settings')
    with op.batch_alter_table('rounds', schema=None) as batch_op:
        batch_op.drop_column('heuristic_thresholds')
    with op.batch_alter_table('label_audits', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_label_audits_round_id'))
        batch_op.drop_index(batch_op.f('ix_label_audits_sample_id'))
        batch_op.drop_index('ix_label_audits_state')
    op.drop_table('label_audits')
