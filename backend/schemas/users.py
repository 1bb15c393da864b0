from __future__ import annotations

from datetime import datetime
from typing import Annotated

from pydantic import ConfigDict, Field

from backend.models.enums import Role
from backend.schemas.base import Public, Strict

# \Z, not $: with $ Python's regex (what schema-driven clients generate from) also matches before a final
# newline, which the default (Rust) engine refuses; the model using it validates with Python's engine too.
# No `\s`: engines disagree on which characters it covers (Python's holds U+0085, a fuzzer's did not), so the
# characters refused are spelled out: controls, space and every other character Python counts as whitespace.
_EMAIL_PART = r"[^@ \x00-\x1f\x7f-\xa0\u1680\u2000-\u200a\u2028\u2029\u202f\u205f\u3000]+"
Email = Annotated[str, Field(min_length=3, max_length=254, pattern=rf"^{_EMAIL_PART}@{_EMAIL_PART}\Z")]
Password = Annotated[str, Field(min_length=8, max_length=256)]


class UserBase(Strict):
    model_config = ConfigDict(regex_engine="python-re")
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


class AccountLock(Public):
    """An account refused logins after too many failures (services.accounts.login_limits), in the answering process."""

    user_id: int
    email: str
    retry_after_s: int = Field(description="Seconds until the account may try again by itself.")


class Unlocked(Public):
    user_id: int
    email: str
    was_locked: bool = Field(description="False: the account had no lock to lift (in the answering process).")
