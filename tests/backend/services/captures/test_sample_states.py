from __future__ import annotations

import pytest

from backend.models.enums import SampleState as S
from backend.services.captures.state_machine import TRANSITIONS, can_transition


@pytest.mark.parametrize(("a", "b"), [
    (S.unlabeled, S.needs_annotation), (S.needs_annotation, S.annotated), (S.annotated, S.fitting),
    (S.fitting, S.fitted), (S.fitted, S.in_review), (S.in_review, S.accepted), (S.in_review, S.rejected),
    (S.in_review, S.needs_annotation), (S.fitted, S.accepted), (S.fitting, S.needs_annotation),
    (S.accepted, S.rejected), (S.accepted, S.needs_annotation),  # an audit that finds the label wrong (issue 40)
])
def test_allowed(a, b):
    assert can_transition(a, b)


@pytest.mark.parametrize(("a", "b"), [
    (S.unlabeled, S.accepted), (S.needs_annotation, S.accepted), (S.annotated, S.accepted),
    (S.fitting, S.accepted), (S.needs_annotation, S.fitted), (S.annotated, S.fitted),
    (S.rejected, S.accepted), (S.unlabeled, S.in_review), (S.accepted, S.in_review), (S.accepted, S.fitting),
])
def test_no_skipping(a, b):
    assert not can_transition(a, b)


def test_accepted_only_from_fitted_or_review():
    assert {a for a, targets in TRANSITIONS.items() if S.accepted in targets} == {S.fitted, S.in_review}
