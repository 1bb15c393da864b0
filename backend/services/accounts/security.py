"""Password hashing (pwdlib, Argon2) and signed, expiring bearer tokens.

A token is `<user id>.<token version>.<expiry unix s>.<HMAC-SHA256>`; the user's token version is bumped
when the password changes or the account is deactivated, which revokes every older token.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import time
from functools import lru_cache

from pwdlib import PasswordHash

from backend.services.errors import AuthError


@lru_cache
def _hasher() -> PasswordHash:
    return PasswordHash.recommended()


def hash_password(password: str) -> str:
    return _hasher().hash(password)


def verify_password(password: str, hashed: str) -> bool:
    try:
        return _hasher().verify(password, hashed)
    except Exception:  # a malformed stored hash is a failed login, not a crash
        return False


def _signature(secret_key: str, payload: str) -> str:
    digest = hmac.new(secret_key.encode(), payload.encode(), hashlib.sha256).digest()
    return base64.urlsafe_b64encode(digest).rstrip(b"=").decode()


def create_token(secret_key: str, user_id: int, token_version: int, lifetime_s: int, now_s: float | None = None) -> str:
    expiry = int((time.time() if now_s is None else now_s) + lifetime_s)
    payload = f"{user_id}.{token_version}.{expiry}"
    return f"{payload}.{_signature(secret_key, payload)}"


def parse_token(secret_key: str, token: str, now_s: float | None = None) -> tuple[int, int]:
    """(user id, token version) of a valid token; AuthError otherwise."""
    parts = token.split(".")
    if len(parts) != 4:
        raise AuthError("malformed access token")
    payload = ".".join(parts[:3])
    if not hmac.compare_digest(parts[3], _signature(secret_key, payload)):
        raise AuthError("invalid access token")
    try:
        user_id, version, expiry = (int(p) for p in parts[:3])
    except ValueError as exc:
        raise AuthError("malformed access token") from exc
    if expiry < (time.time() if now_s is None else now_s):
        raise AuthError("access token expired; log in again")
    return user_id, version
