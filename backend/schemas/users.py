from __future__ import annotations

from datetime import datetime
from typing import Annotated

from pydantic import Field

from backend.models.enums import Role
from backend.schemas.base import Public, Strict

Email = Annotated[str, Field(min_length=3, max_length=254, pattern=r"^[^@\s]+@[^@\s]+$")]
Password = Annotated[str, Field(min_length=8, max_length=256)]


class UserBase(Strict):
    email: Email
    full_name: str = Field(default="", max_length=200)
    role: Role = Role.annotator


class UserCreate(UserBase):
    password: Password


class UserUpdate(Strict):
    full_name: str | None = Field(default=None, max_length=200)
    role: Role | None = None
    is_active: bool | None = None
    password: Password | None = None


class UserPublic(Public):
    id: int
    email: str
    full_name: str
    role: Role
    is_active: bool
    created_at: datetime


class Token(Public):
    access_token: str
    token_type: str = "bearer"
    expires_in: int
