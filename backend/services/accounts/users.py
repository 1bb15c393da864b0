"""Accounts: creation, changes by admins, and login."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Protocol

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from backend.models.enums import Role
from backend.models.users import User
from backend.services import audit
from backend.services.accounts.security import hash_password, verify_password
from backend.services.errors import AuthError, ConflictError, NotFoundError

_DUMMY_HASH: list[str] = []


class Actor(Protocol):
    """Whoever acts in a service call: a `User` row or a request's `Principal` (services need only the id)."""

    @property
    def id(self) -> int: ...


@dataclass(frozen=True, slots=True)
class Principal:
    """The signed-in user of a request: the account's columns without the password hash, read with one Core
    SELECT (no ORM identity map, nothing for the unit of work to track)."""

    id: int
    email: str
    full_name: str
    role: str
    is_active: bool
    token_version: int
    created_at: datetime


_PRINCIPAL = select(User.id, User.email, User.full_name, User.role, User.is_active, User.token_version,
                    User.created_at)


def load_principal(session: Session, user_id: int) -> Principal | None:
    found = session.connection().execute(_PRINCIPAL.where(User.id == user_id)).first()
    return Principal(*found) if found is not None else None


def normalise_email(email: str) -> str:
    return email.strip().lower()


def create_user(session: Session, email: str, password: str, role: Role, full_name: str = "",
                actor_id: int | None = None) -> User:
    email = normalise_email(email)
    if session.execute(select(User.id).where(User.email == email)).first() is not None:
        raise ConflictError(f"a user with email {email!r} already exists")
    user = User(email=email, full_name=full_name, role=Role(role), hashed_password=hash_password(password))
    session.add(user)
    session.flush()
    audit.record(session, actor_id, "user.create", "user", user.id, email=email, role=role.value)
    return user


def get_user(session: Session, user_id: int) -> User:
    user = session.get(User, user_id)
    if user is None:
        raise NotFoundError(f"user {user_id} not found")
    return user


def update_user(session: Session, user_id: int, actor_id: int | None, *, role: Role | None = None,
                is_active: bool | None = None, password: str | None = None, full_name: str | None = None) -> User:
    user = get_user(session, user_id)
    changes: dict[str, object] = {}
    if role is not None and role != user.role:
        if user.role == Role.admin and role != Role.admin:
            _keep_one_admin(session, user)
        user.role, changes["role"] = Role(role), role.value
        user.token_version += 1  # a demoted user's old tokens should not keep the old rights
    if is_active is not None and is_active != user.is_active:
        if not is_active and user.role == Role.admin:
            _keep_one_admin(session, user)
        user.is_active, changes["is_active"] = is_active, is_active
        user.token_version += 1
    if password is not None:
        user.hashed_password = hash_password(password)
        user.token_version += 1
        changes["password"] = "changed"
    if full_name is not None:
        user.full_name, changes["full_name"] = full_name, full_name
    audit.record(session, actor_id, "user.update", "user", user.id, **changes)
    return user


def _keep_one_admin(session: Session, user: User) -> None:
    others = session.execute(
        select(func.count()).select_from(User).where(User.role == Role.admin, User.is_active, User.id != user.id)
    ).scalar_one()
    if others == 0:
        raise ConflictError("this is the last active admin; appoint another admin first")


def authenticate(session: Session, email: str, password: str) -> User:
    user = session.execute(select(User).where(User.email == normalise_email(email))).scalar_one_or_none()
    if user is None:
        if not _DUMMY_HASH:
            _DUMMY_HASH.append(hash_password("not-a-password"))
        verify_password(password, _DUMMY_HASH[0])  # same cost as a real check: no user enumeration by timing
        raise AuthError("incorrect email or password")
    if not verify_password(password, user.hashed_password):
        raise AuthError("incorrect email or password")
    if not user.is_active:
        raise AuthError("this account is deactivated")
    return user
