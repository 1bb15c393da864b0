from __future__ import annotations

from fastapi import APIRouter
from sqlalchemy import select

from backend.api.deps import AdminUser, SessionDep
from backend.models.users import User
from backend.schemas.base import Id
from backend.schemas.users import UserCreate, UserPublic, UserUpdate
from backend.services import users

router = APIRouter(prefix="/admin/users", tags=["admin: users"])


@router.get("", response_model=list[UserPublic])
def list_users(session: SessionDep, _admin: AdminUser) -> list[User]:
    return list(session.execute(select(User).order_by(User.id)).scalars())


@router.post("", response_model=UserPublic, status_code=201)
def create_user(body: UserCreate, session: SessionDep, admin: AdminUser) -> User:
    return users.create_user(session, body.email, body.password, body.role, body.full_name, actor_id=admin.id)


@router.patch("/{user_id}", response_model=UserPublic)
def update_user(user_id: Id, body: UserUpdate, session: SessionDep, admin: AdminUser) -> User:
    return users.update_user(session, user_id, admin.id, role=body.role, is_active=body.is_active,
                             password=body.password, full_name=body.full_name)
