"""Short-lived, sample-scoped tickets for the embedded 3D viewer.

viser's client fetches its recording itself (`?playbackPath=`), so it cannot send the bearer token; the
reviewer's page gets a ticket from an authenticated route instead and puts it in that URL. A ticket
names the user, the user's token version (so a password, role or active-flag change revokes it, like an
access token), the sample and the fit, expires after `TICKET_SECONDS`, and is signed with the server's
secret under its own prefix, so it is no access token and opens nothing else.

Format: `<user id>.<token version>.<sample id>.<fit id>.<expiry unix s>.<HMAC-SHA256 of "scene:" + the rest>`.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import time
from dataclasses import dataclass

from backend.services.errors import AuthError, PermissionDeniedError

TICKET_SECONDS = 15 * 60


@dataclass(frozen=True)
class SceneTicket:
    user_id: int
    sample_id: int
    fit_id: int
    token_version: int


def _signature(secret_key: str, payload: str) -> str:
    digest = hmac.new(secret_key.encode(), f"scene:{payload}".encode(), hashlib.sha256).digest()
    return base64.urlsafe_b64encode(digest).rstrip(b"=").decode()


def issue(secret_key: str, user_id: int, sample_id: int, fit_id: int, *, token_version: int,
          lifetime_s: int = TICKET_SECONDS, now_s: float | None = None) -> str:
    expiry = int((time.time() if now_s is None else now_s) + lifetime_s)
    payload = f"{user_id}.{token_version}.{sample_id}.{fit_id}.{expiry}"
    return f"{payload}.{_signature(secret_key, payload)}"


def verify(secret_key: str, ticket: str, sample_id: int, now_s: float | None = None) -> SceneTicket:
    """The ticket's contents; AuthError if malformed, forged or expired, PermissionDeniedError if it is
    for another sample. The caller compares `token_version` with the user's (services.display.scenes.authorise)."""
    parts = ticket.split(".")
    if len(parts) != 6:
        raise AuthError("malformed scene ticket")
    payload = ".".join(parts[:5])
    if not hmac.compare_digest(parts[5], _signature(secret_key, payload)):
        raise AuthError("invalid scene ticket")
    try:
        user_id, token_version, ticket_sample, fit_id, expiry = (int(p) for p in parts[:5])
    except ValueError as exc:
        raise AuthError("malformed scene ticket") from exc
    if expiry < (time.time() if now_s is None else now_s):
        raise AuthError("scene ticket expired; reload the review page")
    if ticket_sample != sample_id:
        raise PermissionDeniedError(f"this scene ticket is for sample {ticket_sample}, not {sample_id}")
    return SceneTicket(user_id, ticket_sample, fit_id, token_version)
