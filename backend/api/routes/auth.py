from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends
from fastapi.security import OAuth2PasswordRequestForm

from backend.api.deps import AnnotatorUser, SessionDep, SettingsDep
from backend.schemas.users import Token, UserPublic
from backend.services import users
from backend.services.security import create_token

router = APIRouter(prefix="/auth", tags=["auth"])


@router.post("/token", response_model=Token)
def login(session: SessionDep, settings: SettingsDep,
          form: Annotated[OAuth2PasswordRequestForm, Depends()]) -> Token:
    """OAuth2 password flow: `username` is the email. Returns a bearer token."""
    user = users.authenticate(session, form.username, form.password)
    lifetime_s = settings.access_token_minutes * 60
    return Token(access_token=create_token(settings.signing_key, user.id, user.token_version, lifetime_s),
                 expires_in=lifetime_s)


@router.get("/me", response_model=UserPublic)
def me(user: AnnotatorUser) -> UserPublic:
    return UserPublic.model_validate(user)
