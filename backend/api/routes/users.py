from __future__ import annotations

import math

from fastapi import APIRouter, Request
from sqlalchemy import select

from backend.api.deps import AdminUser, SessionDep
from backend.models.users import User
from backend.schemas.base import Id
from backend.schemas.users import AccountLock, Unlocked, UserCreate, UserPublic, UserUpdate
from backend.services import audit
from backend.services.accounts import users
from backend.services.accounts.login_limits import LoginLimiter
from backend.services.review import agreement

router = APIRouter(prefix="/admin/users", tags=["admin: users"])


@router.get("", response_model=list[UserPublic])
def list_users(session: SessionDep, _admin: AdminUser) -> list[User]:
    return list(session.execute(select(User).order_by(User.id)).scalars())


@router.post("", response_model=UserPublic, status_code=201)
def create_user(body: UserCreate, session: SessionDep, admin: AdminUser) -> User:
    return users.create_user(session, body.email, body.password, body.role, body.full_name, actor_id=admin.id)


@router.patch("/{user_id}", response_model=UserPublic)
def update_user(user_id: Id, body: UserUpdate, session: SessionDep, admin: AdminUser) -> User:
    user = users.update_user(session, user_id, admin.id, role=body.role, is_active=body.is_active,
                             password=body.password, full_name=body.full_name)
    if body.is_active is False or body.role is not None:  # the last other annotator gone: no second look waits
        session.flush()
        agreement.release_stranded(session, admin.id)
    return user


@router.get("/locks", response_model=list[AccountLock])
def list_locks(request: Request, session: SessionDep, _admin: AdminUser) -> list[AccountLock]:
    """The accounts locked by failed logins now, with the seconds left (the limits are per server process:
    docs/api.md)."""
    limiter: LoginLimiter = request.app.state.login_limiter
    locks = []
    for user in session.execute(select(User).order_by(User.id)).scalars():
        left = limiter.account_lock_s(users.normalise_email(user.email))
        if left is not None:
            locks.append(AccountLock(user_id=user.id, email=user.email, retry_after_s=max(1, math.ceil(left))))
    return locks


@router.post("/{user_id}/unlock", response_model=Unlocked)
def unlock_user(user_id: Id, request: Request, session: SessionDep, admin: AdminUser) -> Unlocked:
    """Lift the lock that failed logins put on an account (its failures are forgotten), so its owner can sign
    in at once; 404 for an unknown user. The failures of the addresses they came from stay counted."""
    user = users.get_user(session, user_id)
    limiter: LoginLimiter = request.app.state.login_limiter
    was_locked = limiter.unlock(users.normalise_email(user.email))
    audit.record(session, admin.id, "user.unlock", "user", user.id, was_locked=was_locked)
    return Unlocked(user_id=user.id, email=user.email, was_locked=was_locked)
