"""Work in progress on a leased sample, saved as the person works so nothing is lost to a reload."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import ForeignKey, String, UniqueConstraint
from sqlalchemy.orm import Mapped, mapped_column

from backend.db.base import Base, utcnow
from backend.models.enums import LeaseKind, enum_check


class Draft(Base):
    """An annotator's clicks and masks (kind 'annotate') or a reviewer's note (kind 'review') on one sample.

    One per sample, queue and user, read only while holding a live lease of that queue on the sample: its
    author's, or (work left on a lease that lapsed) the sample's next holder's until they save their own.
    `lease_token` is the lease it was saved under; `revision` counts saves (1, 2, ...): the draft's version.
    Deleted when the author submits or decides the sample (backend.services.leases.drafts)."""

    __tablename__ = "drafts"
    __table_args__ = (enum_check("kind", LeaseKind), UniqueConstraint("sample_id", "kind", "user_id"))

    id: Mapped[int] = mapped_column(primary_key=True)
    sample_id: Mapped[int] = mapped_column(ForeignKey("samples.id", ondelete="CASCADE"))
    kind: Mapped[str] = mapped_column(String(20))
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    lease_token: Mapped[str] = mapped_column(String(64))
    revision: Mapped[int]
    payload: Mapped[dict[str, Any]]
    size_bytes: Mapped[int]
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow)
