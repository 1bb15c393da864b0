"""Verification decisions and bootstrap rounds D_i with their members by stream."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import ForeignKey, String, Text
from sqlalchemy.orm import Mapped, mapped_column

from backend.db.base import Base, utcnow
from backend.models.enums import DecisionKind, RoundState, Stream, enum_check


class Decision(Base):
    """Accept / reject / annotate / discard, by a reviewer or (user_id NULL, by_heuristic) the heuristic."""

    __tablename__ = "decisions"
    __table_args__ = (enum_check("decision", DecisionKind),)

    id: Mapped[int] = mapped_column(primary_key=True)
    sample_id: Mapped[int] = mapped_column(ForeignKey("samples.id", ondelete="CASCADE"), index=True)
    fit_id: Mapped[int | None] = mapped_column(ForeignKey("fits.id", ondelete="SET NULL"))
    round_id: Mapped[int | None] = mapped_column(ForeignKey("rounds.id", ondelete="SET NULL"))
    user_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    by_heuristic: Mapped[bool] = mapped_column(default=False)
    decision: Mapped[str] = mapped_column(String(20))
    reason: Mapped[str] = mapped_column(Text, default="")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Round(Base):
    """Bootstrap round i: collects D^h_i, D^m_i, D^l_i; D_{i+1} = D_i + those."""

    __tablename__ = "rounds"
    __table_args__ = (enum_check("state", RoundState),)

    id: Mapped[int] = mapped_column(primary_key=True)
    index: Mapped[int] = mapped_column(unique=True)
    state: Mapped[str] = mapped_column(String(20), default=RoundState.running)
    mvnet_version: Mapped[str | None] = mapped_column(String(100))
    handsegnet_version: Mapped[str | None] = mapped_column(String(100))
    note: Mapped[str] = mapped_column(Text, default="")
    counts: Mapped[dict[str, Any]] = mapped_column(default=dict)
    created_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    finished_at: Mapped[datetime | None]
    failure: Mapped[str | None] = mapped_column(Text)  # why its job failed (state 'failed')
    # The heuristic's thresholds chosen at launch and why (review.precision_target, issue 40); None: the paper's.
    heuristic_thresholds: Mapped[dict[str, Any] | None] = mapped_column(default=None)


class RoundMember(Base):
    """A sample accepted into the dataset during a round, by one stream. Accepted once, so unique."""

    __tablename__ = "round_members"
    __table_args__ = (enum_check("stream", Stream),)

    id: Mapped[int] = mapped_column(primary_key=True)
    round_id: Mapped[int] = mapped_column(ForeignKey("rounds.id", ondelete="CASCADE"), index=True)
    sample_id: Mapped[int] = mapped_column(ForeignKey("samples.id", ondelete="CASCADE"), unique=True)
    fit_id: Mapped[int | None] = mapped_column(ForeignKey("fits.id", ondelete="SET NULL"))
    stream: Mapped[str] = mapped_column(String(20))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
