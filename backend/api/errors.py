"""The one place where domain errors become HTTP responses: {"detail": "<message>"}."""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import IntegrityError, OperationalError

from backend.services.errors import (
    AuthError,
    ConflictError,
    DomainError,
    InvalidInputError,
    LeaseExpiredError,
    NotFoundError,
    PermissionDeniedError,
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
    (ServiceUnavailableError, 503),
]


def status_of(exc: DomainError) -> int:
    for cls, status in STATUS:
        if isinstance(exc, cls):
            return status
    return 400


def _location(loc: tuple) -> str:
    parts = [str(p) for p in loc if p not in ("body",)]
    return ".".join(parts) or "body"


def install(app: FastAPI) -> None:
    @app.exception_handler(DomainError)
    async def _domain(_request: Request, exc: DomainError) -> JSONResponse:
        status = status_of(exc)
        headers = {"WWW-Authenticate": "Bearer"} if status == 401 else {"Retry-After": "5"} if status == 503 else None
        return JSONResponse({"detail": exc.message}, status_code=status, headers=headers)

    @app.exception_handler(RequestValidationError)
    async def _validation(_request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = exc.errors()
        if any(e.get("type") == "json_invalid" for e in errors):
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

    @app.exception_handler(OperationalError)
    async def _operational(_request: Request, exc: OperationalError) -> JSONResponse:
        logger.warning("database unavailable or busy: %s", exc.orig)
        return JSONResponse({"detail": "database busy; nothing was written, retry"}, status_code=503,
                            headers={"Retry-After": "1"})
