"""The one place where domain errors become HTTP responses: {"detail": "<message>"}."""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DataError, IntegrityError, OperationalError
from starlette.exceptions import HTTPException

from backend.api.deps import bearer, depends_on, get_current_user
from backend.services.errors import (
    AuthError,
    ConflictError,
    DomainError,
    InvalidInputError,
    LeaseExpiredError,
    NotFoundError,
    PermissionDeniedError,
    RateLimitedError,
    ServiceUnavailableError,
    TooLargeError,
)

logger = logging.getLogger(__name__)

STATUS: list[tuple[type[DomainError], int]] = [
    (NotFoundError, 404),
    (AuthError, 401),
    (PermissionDeniedError, 403),
    (InvalidInputError, 422),
    (LeaseExpiredError, 409),
    (ConflictError, 409),
    (TooLargeError, 413),
    (RateLimitedError, 429),
    (ServiceUnavailableError, 503),
]


def _routing_refusal(request: Request, exc: HTTPException) -> str:
    """Routing's own 404 and 405 in words: what was asked, and what to do instead."""
    path = request.url.path
    if exc.status_code == 405:
        allowed = (exc.headers or {}).get("Allow", "")
        return f"{request.method} is not allowed on {path}; use {allowed} (the API's operations: /docs)"
    return f"no such API path {path!r}; the API's operations are listed at /docs"


def status_of(exc: DomainError) -> int:
    for cls, status in STATUS:
        if isinstance(exc, cls):
            return status
    return 400


def domain_response(exc: DomainError) -> JSONResponse:
    """A domain error as the API answers it: {"detail": message}, its status, and the headers the status calls for
    (401: WWW-Authenticate; 429, 503: Retry-After). The app's handler and the annotators' hot path both answer so."""
    status = status_of(exc)
    headers = None
    if status == 401:
        headers = {"WWW-Authenticate": "Bearer"}
    elif isinstance(exc, RateLimitedError):
        headers = {"Retry-After": str(exc.retry_after_s)}
    elif status == 503:
        headers = {"Retry-After": "5"}
    return JSONResponse({"detail": exc.message}, status_code=status, headers=headers)


def _location(loc: tuple) -> str:
    parts = [str(p) for p in loc if p not in ("body",)]
    return ".".join(parts) or "body"


async def _unauthenticated(request: Request) -> JSONResponse | None:
    """The 401 a caller without a valid token gets on a route that needs one, else None.

    FastAPI parses a JSON body before it resolves the route's dependencies, so a body it cannot parse would be
    answered before authentication; this runs the same check (services.accounts.security, the user's row) first."""
    route = request.scope.get("route")
    dependant = getattr(route, "dependant", None)
    if dependant is None or not depends_on(dependant, get_current_user):
        return None
    try:
        await get_current_user(request, request.app.state.settings, await bearer(request))
    except AuthError as exc:
        return JSONResponse({"detail": exc.message}, status_code=401, headers={"WWW-Authenticate": "Bearer"})
    except OperationalError as exc:  # raised in a handler it would be a 500
        logger.warning("database unavailable or busy: %s", exc.orig)
        return JSONResponse({"detail": "database busy; nothing was written, retry"}, status_code=503,
                            headers={"Retry-After": "1"})
    return None


def _unparseable_body(exc: BaseException | None) -> str | None:
    """What is wrong with a body FastAPI could not parse (it answers a bare 400), if we can say."""
    if isinstance(exc, UnicodeDecodeError):
        return f"the body is not UTF-8 text (byte {exc.start} cannot be decoded): send JSON as UTF-8"
    if isinstance(exc, RecursionError):
        return "the JSON body is nested too deeply to be read"
    return None


def install(app: FastAPI) -> None:
    @app.exception_handler(DomainError)
    async def _domain(_request: Request, exc: DomainError) -> JSONResponse:
        return domain_response(exc)

    @app.exception_handler(HTTPException)
    async def _http(request: Request, exc: HTTPException) -> JSONResponse:
        problem = _unparseable_body(exc.__cause__) if exc.status_code == 400 else None
        if (exc.status_code in (404, 405) and exc.detail in ("Not Found", "Method Not Allowed")
                and request.url.path.startswith("/api")):
            return JSONResponse({"detail": _routing_refusal(request, exc)}, status_code=exc.status_code,
                                headers=exc.headers)
        if problem is None:
            return await http_exception_handler(request, exc)
        refused = await _unauthenticated(request)
        return refused or JSONResponse({"detail": problem, "errors": [{"loc": ["body"], "msg": problem,
                                                                        "type": "body_unreadable"}]}, status_code=422)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = exc.errors()
        if any(e.get("type") == "json_invalid" for e in errors):
            refused = await _unauthenticated(request)  # the body was read before the token was checked
            if refused is not None:
                return refused
            first = next(e for e in errors if e.get("type") == "json_invalid")
            message = f"malformed JSON: {first.get('ctx', {}).get('error', 'cannot parse the body')}"
        else:
            message = "; ".join(f"{_location(tuple(e['loc']))}: {e['msg']}" for e in errors[:10])
        details = [{"loc": list(e["loc"]), "msg": e["msg"], "type": e["type"]} for e in errors[:50]]
        return JSONResponse({"detail": message, "errors": details}, status_code=422)

    @app.exception_handler(IntegrityError)
    async def _integrity(_request: Request, exc: IntegrityError) -> JSONResponse:
        logger.info("integrity error: %s", exc.orig)
        return JSONResponse({"detail": "conflicting concurrent change; nothing was written, retry"},
                            status_code=409)

    @app.exception_handler(DataError)
    async def _data(_request: Request, exc: DataError) -> JSONResponse:
        # A value the database refuses to store (PostgreSQL: a NUL character in a query parameter or a form
        # field, which the body schemas already refuse); the transaction was rolled back.
        logger.info("data the database refused: %s", exc.orig)
        message = str(exc.orig).splitlines()[0] if exc.orig is not None else "a value the database cannot store"
        return JSONResponse({"detail": f"a value cannot be stored: {message}; nothing was written"}, status_code=422)

    @app.exception_handler(OperationalError)
    async def _operational(_request: Request, exc: OperationalError) -> JSONResponse:
        logger.warning("database unavailable or busy: %s", exc.orig)
        return JSONResponse({"detail": "database busy; nothing was written, retry"}, status_code=503,
                            headers={"Retry-After": "1"})
