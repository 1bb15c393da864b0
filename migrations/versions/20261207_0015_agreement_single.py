"""agreement_single: a picked sample annotated once, for want of a second annotator

Issue 40: an agreement pair may end 'single': the sample was picked for a second, blind look, but no other active
annotator exists (or is left) to take it, so the first look's fit is the label and goes to review as any annotated
fit (services.review.agreement). Only the state check constraint changes.

Revision ID: 0015_agreement_single
Revises: 0014_agreement
Create Date: 2026-12-07 09:00:00
"""

from __future__ import annotations

from collections.abc import Sequence

from alembic import op

revision: str = '0015_agreement_single'
down_revision: str | None = '0014_agreement'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_STATES_BEFORE = "state IN ('second_look', 'done')"
_STATES_AFTER = "state IN ('second_look', 'done', 'single')"


def upgrade() -> None:
    with op.batch_alter_table('agreement_pairs', schema=None) as batch_op:
        batch_op.drop_constraint(op.f('ck_agreement_pairs_state_valid'), type_='check')
        batch_op.create_check_constraint(op.f('ck_agreement_pairs_state_valid'), _STATES_AFTER)


def downgrade() -> None:
    # A 'single' pair has no second look: the sample went on as an ordinary annotated one, so the row goes.
    op.execute("DELETE FROM agreement_pairs WHERE state = 'single'")
    with op.batch_alter_table('agreement_pairs', schema=None) as batch_op:
        batch_op.drop_constraint(op.f('ck_agreement_pairs_state_valid'), type_='check')
        batch_op.create_check_constraint(op.f('ck_agreement_pairs_state_valid'), _STATES_BEFORE)
