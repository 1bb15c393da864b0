"""discard_decision: a reviewer may discard a fit from predictions

Issue 37: the paper's reviewers, for a fit that is not good enough, either discarded the sample or annotated it; a
'discard' decision leaves the sample in the pool (state 'fitted') for the next round's networks to predict and fit
again, without the annotators' time. Only the decision check constraint changes.

Revision ID: 0016_discard_decision
Revises: 0015_agreement_single
Create Date: 2026-12-07 09:10:00
"""

from __future__ import annotations

from collections.abc import Sequence

from alembic import op

revision: str = '0016_discard_decision'
down_revision: str | None = '0015_agreement_single'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_DECISIONS_BEFORE = "decision IN ('accept', 'reject', 'annotate')"
_DECISIONS_AFTER = "decision IN ('accept', 'reject', 'annotate', 'discard')"


def upgrade() -> None:
    with op.batch_alter_table('decisions', schema=None) as batch_op:
        batch_op.drop_constraint(op.f('ck_decisions_decision_valid'), type_='check')
        batch_op.create_check_constraint(op.f('ck_decisions_decision_valid'), _DECISIONS_AFTER)


def downgrade() -> None:
    # A discard on a blind audit sent the label to the annotators, as 'annotate' does: it becomes one. Any other
    # discard moved nothing final (the sample went back to 'fitted'): the row goes, the audit log keeps it.
    op.execute("UPDATE decisions SET decision = 'annotate' WHERE decision = 'discard' AND id IN "
               "(SELECT decision_id FROM label_audits WHERE decision_id IS NOT NULL)")
    op.execute("DELETE FROM decisions WHERE decision = 'discard'")
    with op.batch_alter_table('decisions', schema=None) as batch_op:
        batch_op.drop_constraint(op.f('ck_decisions_decision_valid'), type_='check')
        batch_op.create_check_constraint(op.f('ck_decisions_decision_valid'), _DECISIONS_BEFORE)
