"""The simulated team's turns: a queue is done only when no one in the role can take a task."""

from __future__ import annotations

from types import SimpleNamespace

from backend.simulation.team import Team, TeamWork


class _Annotator:
    def __init__(self, samples: list[int]) -> None:
        self.samples = list(samples)

    def annotate_next(self, round_index, give_up, attempts):
        return SimpleNamespace(sample_id=self.samples.pop(0)) if self.samples else None


def test_annotators_go_on_while_one_of_them_still_gets_a_task():
    """The first annotator is passed over (an agreement's second look is never theirs); the second takes both."""
    team = Team([_Annotator([]), _Annotator([7, 8])], [object()])
    work = TeamWork()
    assert team.annotate_all(0, work) == 2
    assert [a.sample_id for a in work.annotations] == [7, 8]


def test_the_limit_still_stops_the_first_pass():
    team = Team([_Annotator([1, 3]), _Annotator([2, 4])], [object()])
    assert team.annotate_all(0, TeamWork(), limit=3) == 3
