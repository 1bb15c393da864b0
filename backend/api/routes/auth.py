from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Form, Request

from backend.api.deps import AnnotatorUser, SessionDep, SettingsDep
from backend.schemas.users import Token, UserPublic
from backend.services.accounts import users
from backend.services.accounts.login_limits import LoginLimiter
from backend.services.accounts.security import create_token
from backend.services.errors import AuthError

router = APIRouter(prefix="/auth", tags=["auth"])


@router.post("/token", response_model=Token, responses={401: {}, 429: {}})
def login(request: Request, session: SessionDep, settings: SettingsDep,
          username: Annotated[str, Form(min_length=1, max_length=254, description="The account's email.")],
          password: Annotated[str, Form(min_length=1, max_length=256)]) -> Token:
    """OAuth2 password flow: `username` is the email. Returns a bearer token.

    429 with Retry-After after too many failed logins for the account or from the client's address, or when
    the server is busy checking other passwords (services.accounts.login_limits)."""
    limiter: LoginLimiter = request.app.state.login_limiter
    account = users.normalise_email(username)
    address = request.client.host if request.client else "unknown"
    limiter.check(account, address)  # before hashing: a locked account costs the server nothing
    try:
        with limiter.hashing():
            user = users.authenticate(session, username, password)
    except AuthError:
        limiter.failed(account, address)
        raise
    limiter.succeeded(account)
    lifetime_s = settings.access_token_minutes * 60
    return Token(access_token=create_token(settings.signing_key, user.id, user.token_version, lifetime_s),
                 expires_in=lifetime_s)


@router.get("/me", response_model=UserPublic)
def me(user: AnnotatorUser) -> UserPublic:
    return UserPublic.model_validate(user)
