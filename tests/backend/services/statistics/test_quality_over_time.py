"""Per-person quality over time (issue 40, services.statistics.team_statistics.quality_over_time): each person's
figures this week against their earlier weeks and the team median, from hand-made work and through the API."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from backend.models.enums import Role
from backend.services.statistics.team_statistics import Work, quality_over_time, week_of

EARLIER = datetime(2026, 11, 24, 10, 0, tzinfo=UTC)  # a Tuesday
NOW = EARLIER + timedelta(days=7)  # the next week's Tuesday


def test_each_person_against_their_earlier_weeks_and_the_team_median(sqlite_env):
    a, r, m = (sqlite_env.user_ids[role] for role in (Role.annotator, Role.reviewer, Role.admin))
    items = [
        # The annotator: 1 of 2 accepted before, 2 of 2 now; a sample submitted twice counts once for its seconds.
        Work("accept_rate", a, EARLIER, 1.0, ("s", 1)), Work("accept_rate", a, EARLIER, 0.0, ("s", 2)),
        Work("accept_rate", a, NOW, 1.0, ("s", 3)), Work("accept_rate", a, NOW, 1.0, ("s", 4)),
        Work("seconds_per_sample", a, NOW, 30.0, 10), Work("seconds_per_sample", a, NOW, 10.0, 10),
        Work("seconds_per_sample", a, NOW, 20.0, 11),
        # The admin annotates too: 0 of 1 accepted now.
        Work("accept_rate", m, NOW, 0.0, ("s", 5)),
        # The reviewer: overturned once in one decision before, none of two now; one gold look now, agreed.
        Work("overturned_rate", r, EARLIER, 1.0, 1), Work("overturned_rate", r, NOW, 0.0, 2),
        Work("overturned_rate", r, NOW, 0.0, 3), Work("gold_agreement", r, NOW, 1.0, 7),
    ]
    with sqlite_env.session() as session:
        out = quality_over_time(session, items)
    assert out["current_week"] == "2026-11-30"  # the Monday of the newest week anyone worked
    people = {p["user_id"]: p["figures"] for p in out["people"]}
    assert set(people) == {a, r, m}
    accept = people[a]["accept_rate"]
    assert (accept["current"], accept["earlier"]) == ({"value": 1.0, "n": 2}, {"value": 0.5, "n": 2})
    assert [(w["week"], w["value"]) for w in accept["weeks"]] == [("2026-11-23", 0.5), ("2026-11-30", 1.0)]
    assert people[a]["seconds_per_sample"]["current"] == {"value": 30.0, "n": 2}  # (30 + 10 + 20) s / 2 samples
    assert people[a]["seconds_per_sample"]["earlier"] == {"value": None, "n": 0}
    assert people[r]["overturned_rate"]["current"]["value"] == 0.0
    assert people[r]["overturned_rate"]["earlier"]["value"] == 1.0
    median = out["team_median"]
    assert median["accept_rate"] == {"current": 0.5, "earlier": 0.5}  # (1.0, 0.0) now; 0.5 alone before
    assert median["gold_agreement"] == {"current": 1.0, "earlier": None}
    assert median["seconds_per_decision"] == {"current": None, "earlier": None}
    assert [f["name"] for f in out["figures"]] == ["accept_rate", "seconds_per_sample", "overturned_rate",
                                                   "gold_agreement", "seconds_per_decision"]


def test_nobody_worked_yet(sqlite_env):
    with sqlite_env.session() as session:
        out = quality_over_time(session, [])
    assert out["current_week"] is None and out["people"] == []
    assert all(v == {"current": None, "earlier": None} for v in out["team_median"].values())


@pytest.mark.parametrize("at", [datetime(2026, 11, 30, 0, 0), datetime(2026, 12, 6, 23, 59, tzinfo=UTC)])
def test_a_week_starts_on_monday_in_utc(at):
    assert week_of(at) == datetime(2026, 11, 30, tzinfo=UTC)


def test_the_quality_page_reads_each_persons_figures(env, h):
    (sample_id,) = h.seed(env, frames=1, cameras=1, state="needs_annotation")
    task = h.next_task(env)
    assert env.client.post(f"/api/annotate/samples/{sample_id}/submissions", json=h.body(task),
                           headers=env.headers(Role.annotator)).status_code == 201
    h.set_state(env, [sample_id], "fitting")
    h.record_fit(env, sample_id, from_clicks=True)
    h.next_task(env, Role.reviewer, "review")
    assert env.client.post(f"/api/review/samples/{sample_id}/decision", json={"decision": "accept"},
                           headers=env.headers(Role.reviewer)).status_code == 201
    response = env.client.get("/api/admin/quality", headers=env.headers(Role.admin))
    assert response.status_code == 200, response.text
    people = {p["user_id"]: p["figures"] for p in response.json()["people"]["people"]}
    annotator = people[env.user_ids[Role.annotator]]
    assert annotator["accept_rate"]["current"] == {"value": 1.0, "n": 1}
    assert annotator["seconds_per_sample"]["current"] == {"value": 12.5, "n": 1}
    assert people[env.user_ids[Role.reviewer]]["overturned_rate"]["current"] == {"value": 0.0, "n": 1}
    assert response.json()["people"]["team_median"]["accept_rate"]["current"] == 1.0
