"""The project's labelling guidelines: text and images an admin edits, shown on the annotate and review pages."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import ForeignKey, Text
from sqlalchemy.orm import Mapped, mapped_column

from backend.db.base import Base, utcnow


class Guidelines(Base):
    """One row (id 1) once an admin saved guidelines. `images`: [{"id", "key", "caption", "content_type"}] in the
    order shown, the files in storage under `key`; `revision` counts saves, so a save made on an older revision
    (another admin saved meanwhile) is refused rather than silently overwriting theirs."""

    __tablename__ = "guidelines"

    id: Mapped[int] = mapped_column(primary_key=True)
    text: Mapped[str] = mapped_column(Text, default="")
    images: Mapped[list[Any]] = mapped_column(default=list)
    revision: Mapped[int] = mapped_column(default=0)
    updated_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"))
    updated_at: Mapped[datetime] = mapped_column(default=utcnow)
