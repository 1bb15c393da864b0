"""Request dependencies as Annotated aliases: one database transaction per request, the current user,
role checks written once."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable, Iterator
from contextlib import contextmanager
from typing import Annotated, Any

import anyio
from fastapi import Depends, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from backend.models.enums import Role
from backend.services.accounts.auth_cache import AuthCache
from backend.services.accounts.security import parse_token
from backend.services.accounts.users import Principal, load_principal
from backend.services.captures.storage import Storage
from backend.services.errors import AuthError, PermissionDeniedError
from backend.services.jobs.jobs import JobQueue
from backend.services.transactions import discard_after_commit, run_after_commit
from backend.settings import Settings


async def get_settings(request: Request) -> Settings:  # async: no I/O, so no thread-pool hop
    return request.app.state.settings


_SAFE_METHODS = frozenset({"GET", "HEAD"})


async def get_session(request: Request) -> AsyncIterator[Session]:
    """One transaction per request: committed when the route returns (before the response is sent),
    rolled back on any error, so a failed request writes nothing.

    Async, with only the commit (or rollback) in the thread pool: creating a session does no I/O (the
    connection is taken at its first statement), and each thread-pool hop showed in the profile.
    GET and HEAD requests only read: their transactions do not take SQLite's writer lock
    (backend.db.session.read_only_engine), so image serving never queues behind submissions.

    A route that commits itself, in its own thread, gives the connection back to the pool before the route's
    thread is freed, so a request never holds a pooled connection while it waits for a thread (with more
    requests in flight than threads and connections, e.g. a thousand idle-paced annotators, that wait exhausted
    the pool). The annotators' two hot routes open and end their transaction themselves (`route_session`)."""
    state = request.app.state
    factory = state.read_session_factory if request.method in _SAFE_METHODS else state.session_factory
    session: Session = factory()
    try:
        yield session
    except BaseException:
        with anyio.CancelScope(shield=True):  # even when the client went away: give the connection back
            await run_in_threadpool(_abort, session)
        raise
    if session.in_transaction():
        with anyio.CancelScope(shield=True):
            await run_in_threadpool(_commit, session)
    else:  # the route committed in its own thread (the annotators' hot path): no second thread-pool hop
        session.close()
    run_after_commit(session)


@contextmanager
def state_session(state: Any) -> Iterator[Session]:
    """get_session's transaction, opened and ended by a (sync) route in its own thread, on the app's `state`:
    committed when the block ends (a failed commit raises, the request writes nothing), rolled back on any error,
    closed either way, then the after-commit work (the fit hand-off). For the annotators' two hot routes: the
    generator dependency cost the event loop an exit stack and a shielded exit per request (~0.4 ms of server CPU
    per cycle, measured)."""
    session: Session = state.session_factory()
    try:
        yield session
        session.commit()
    except BaseException:
        _abort(session)
        raise
    session.close()
    run_after_commit(session)


def read_principal(state: Any, user_id: int) -> Principal | None:
    """The user's row, read in a transaction of its own (its connection back in the pool on return) and kept in
    the process's cache; None when there is no such user. Blocking: call it from a thread."""
    cache: AuthCache = state.auth_cache
    generation = cache.generation(user_id)
    with state.read_session_factory() as session:
        if session.get_bind().dialect.name == "postgresql":  # one round trip: no BEGIN before it, no ROLLBACK after
            session.connection(execution_options={"isolation_level": "AUTOCOMMIT"})
        user = load_principal(session, user_id)
    if user is not None:
        cache.put(user, generation)
    return user


def _commit(session: Session) -> None:
    try:
        session.commit()
    except BaseException:
        _abort(session)
        raise
    session.close()


def _abort(session: Session) -> None:
    try:
        session.rollback()
        discard_after_commit(session)
    finally:
        session.close()


async def get_job_queue(request: Request) -> JobQueue:
    return request.app.state.job_queue


async def get_storage(request: Request) -> Storage:
    return request.app.state.storage


SettingsDep = Annotated[Settings, Depends(get_settings)]
SessionDep = Annotated[Session, Depends(get_session, scope="function")]
JobQueueDep = Annotated[JobQueue, Depends(get_job_queue)]
StorageDep = Annotated[Storage, Depends(get_storage)]

bearer = HTTPBearer(auto_error=False, description="Token from POST /api/auth/token")


async def get_current_user(
    request: Request,
    settings: SettingsDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
) -> Principal:
    """The token's user, from the process's short-lived cache (services.accounts.auth_cache) or, on a miss or when the
    token is newer than the cached row, one Core SELECT in a read transaction of its own, whose connection is
    back in the pool when the thread-pool call returns (the request's own session takes one only in the
    route's thread)."""
    if credentials is None:
        raise AuthError("not authenticated: send 'Authorization: Bearer <token>'")
    user_id, version = parse_token(settings.signing_key, credentials.credentials)
    state = request.app.state
    user = state.auth_cache.get(user_id)
    if user is None or user.token_version < version:
        user = await run_in_threadpool(read_principal, state, user_id)
    return checked_principal(user, version)


CurrentUser = Annotated[Principal, Depends(get_current_user, scope="function")]


def bearer_claims(state: Any, authorization: bytes | None) -> tuple[int, int] | None:
    """(user id, token version) of an `Authorization` header's valid bearer token, with no I/O; None in every
    other case, including every error (then `get_current_user` decides and says what is wrong). For
    backend.api.hot_path."""
    if authorization is None:
        return None
    scheme, _, token = authorization.decode("latin-1").partition(" ")
    if scheme.lower() != "bearer" or not token:
        return None
    try:
        return parse_token(state.settings.signing_key, token)
    except AuthError:
        return None


def current_principal(state: Any, user_id: int, version: int) -> Principal:
    """The user a valid token names, as `get_current_user` finds it (the cache, else the row, read here:
    blocking), checked as it checks it (`checked_principal`: AuthError when revoked or deactivated)."""
    user = state.auth_cache.get(user_id)
    if user is None or user.token_version < version:
        user = read_principal(state, user_id)
    return checked_principal(user, version)


def checked_principal(user: Principal | None, version: int) -> Principal:
    """The token's user if the token is current (its version the row's) and the account active; else AuthError
    naming which. The one check of `get_current_user` and the annotators' hot path (backend.api.hot_path)."""
    if user is None or user.token_version != version:
        raise AuthError("access token revoked; log in again")
    if not user.is_active:
        raise AuthError("this account is deactivated")
    return user


def checked_role(user: Principal, minimum: Role) -> Principal:
    """`user` if their role ranks at least `minimum` (annotator < reviewer < admin); else PermissionDeniedError.
    The one check of `require_role` and the annotators' hot path."""
    if Role(user.role).rank < minimum.rank:
        raise PermissionDeniedError(f"this needs the {minimum.value} role; you are {user.role}")
    return user


def depends_on(dependant: Any, call: Callable[..., Any]) -> bool:
    """Whether a route's dependency tree (`route.dependant`) includes `call`, directly or not."""
    return any(sub.call is call or depends_on(sub, call) for sub in dependant.dependencies)


def require_role(minimum: Role) -> Callable[[Principal], Principal]:
    """Dependency admitting users whose role ranks at least `minimum` (annotator < reviewer < admin)."""

    async def check(user: CurrentUser) -> Principal:  # async: no I/O, so no thread-pool hop
        return checked_role(user, minimum)

    check.__name__ = f"require_{minimum.value}"
    return check


AnnotatorUser = Annotated[Principal, Depends(require_role(Role.annotator), scope="function")]
ReviewerUser = Annotated[Principal, Depends(require_role(Role.reviewer), scope="function")]
AdminUser = Annotated[Principal, Depends(require_role(Role.admin), scope="function")]
