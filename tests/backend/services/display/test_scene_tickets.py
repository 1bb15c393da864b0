from __future__ import annotations

import pytest

from backend.services.accounts.security import create_token, parse_token
from backend.services.display import scene_tickets
from backend.services.errors import AuthError, PermissionDeniedError

SECRET = "a-secret-for-the-tests-0123"


def test_round_trip_and_scope():
    ticket = scene_tickets.issue(SECRET, 7, 42, 9, token_version=3, now_s=1000.0)
    assert scene_tickets.verify(SECRET, ticket, 42, now_s=1000.0) == scene_tickets.SceneTicket(7, 42, 9, 3)
    with pytest.raises(PermissionDeniedError, match="for sample 42"):
        scene_tickets.verify(SECRET, ticket, 43, now_s=1000.0)
    with pytest.raises(AuthError, match="expired"):
        scene_tickets.verify(SECRET, ticket, 42, now_s=1000.0 + scene_tickets.TICKET_SECONDS + 1)
    with pytest.raises(AuthError, match="invalid"):
        scene_tickets.verify("another-secret-0123456789", ticket, 42, now_s=1000.0)


def test_tickets_and_access_tokens_do_not_open_each_other():
    token = create_token(SECRET, 7, 0, 3600)
    with pytest.raises(AuthError):
        scene_tickets.verify(SECRET, token, 0)
    ticket = scene_tickets.issue(SECRET, 7, 42, 9, token_version=0)
    with pytest.raises(AuthError):
        parse_token(SECRET, ticket)
    # Same field count as a token with one field dropped: the signature's prefix still tells them apart.
    parts = ticket.split(".")
    with pytest.raises(AuthError):
        parse_token(SECRET, ".".join(parts[:3] + parts[5:]))
