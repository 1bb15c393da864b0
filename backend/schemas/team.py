"""Per-person statistics (services.statistics.team_statistics gives the definitions)."""

from __future__ import annotations

from pydantic import Field

from backend.models.enums import Role
from backend.schemas.base import Public


class PersonStatistics(Public):
    user_id: int
    email: str
    full_name: str
    role: Role
    samples: int = Field(description="Distinct samples they submitted.")
    submissions: int
    points_placed: int = Field(description="Points placed by hand (visible or occluded), not from proposals.")
    proposals_accepted: int = Field(description="Points taken from a proposal.")
    seconds_per_sample: float | None = Field(description="Active seconds of their submissions per sample.")
    decided: int = Field(description="Their submissions a person has decided on since.")
    accepted: int = Field(description="Of those, accepted.")
    accept_rate: float | None = Field(description="accepted / decided (None while nothing is decided).")
    decisions: int = Field(description="Review decisions they made.")
    seconds_per_decision: float | None = Field(description="From the review page's activity logs.")
    overturned: int = Field(description="Their decisions someone else later decided differently on the same fit.")
    gold_judged: int = Field(default=0, description="Gold labels slipped into their review queue and decided.")
    gold_agreement: float | None = Field(default=None, description="Share of those they accepted (gold is right).")
