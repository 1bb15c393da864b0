"""The annotators' two hot routes answered without FastAPI's routing and dependency layers, when the request is plain.

`POST /api/annotate/next` and `POST /api/annotate/samples/{id}/submissions` are most of the API's traffic (a
crowd of annotators loops next -> submit). FastAPI matches the route among all of the API's routers, builds the
request and solves its dependency tree (settings, bearer scheme, user, role, queue, storage, the body's model)
and wraps the call in exception and exit-stack layers; that per-request work was a large share of the server's
CPU per cycle (docs/benchmarks.md, issue 17). This middleware answers such a request itself when the caller's
bearer token is well-formed and signed, the path's sample id a plain integer in range, the query string empty and
the body JSON that `SubmissionCreate` accepts. It then does what the route does, with the same functions, in the
thread pool: the user checked as `get_current_user` and `require_role` check (`checked_principal`, `checked_role`;
from the process's auth cache, else read in the route's thread: one thread-pool hop per request either way), then
the routes' own work (`next_response`, `submit_response`: the one checked service call, `queues.acquire` or
`submissions.submit`). A refusal (a DomainError: revoked token, stale lease, click outside the image, ...) is
answered as the app's handler answers it (`backend.api.errors.domain_response`), byte for byte what the route says.

Everything else goes on to FastAPI's route, with the body replayed, which answers exactly as it would have:
- requests that are not plain (no or a malformed token, a query string, another content type, a body that is not
  JSON or that the schema refuses): FastAPI words those answers (422's error list, the 401 of a bad token);
- a failure of the attempt itself (a database error, a bug): logged with its reason, then the route runs the work
  again. A failed attempt wrote nothing (the work's transaction rolled back; PostgreSQL's one-statement submit
  writes all or nothing) and both routes are idempotent (a held lease is renewed, a submission id already stored
  is answered as a duplicate), so running the route again is safe.

It sits inside the security-header and body-size middlewares (app.py), so their headers and limits apply.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from pydantic import ValidationError
from sqlalchemy.exc import SQLAlchemyError
from starlette.concurrency import run_in_threadpool
from starlette.responses import Response

from backend.api.deps import bearer_claims, checked_role, current_principal
from backend.api.errors import domain_response
from backend.api.routes.annotate import next_response, submit_response
from backend.models.enums import Role
from backend.schemas.base import MAX_ID
from backend.schemas.tasks import SubmissionCreate
from backend.services.errors import DomainError

logger = logging.getLogger(__name__)

NEXT_PATH = "/api/annotate/next"
SUBMIT_PREFIX, SUBMIT_SUFFIX = "/api/annotate/samples/", "/submissions"
_JSON_TYPES = (b"application/json", b"application/json; charset=utf-8")

Scope = dict[str, Any]
Receive = Callable[[], Awaitable[dict[str, Any]]]
Send = Callable[[dict[str, Any]], Awaitable[None]]


def submit_sample_id(path: str) -> int | None:
    """The sample id of a submissions path, if it is a plain decimal integer in the API's id range."""
    if not (path.startswith(SUBMIT_PREFIX) and path.endswith(SUBMIT_SUFFIX)):
        return None
    digits = path[len(SUBMIT_PREFIX):-len(SUBMIT_SUFFIX)]
    if not digits.isascii() or not digits.isdigit() or len(digits) > 10 or digits[0] == "0":
        return None
    value = int(digits)
    return value if value <= MAX_ID else None


class AnnotatorHotPath:
    """ASGI middleware: the module's docstring."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "POST" or scope.get("query_string"):
            await self.app(scope, receive, send)
            return
        path = scope["path"]
        sample_id = None
        if path != NEXT_PATH:
            sample_id = submit_sample_id(path)
            if sample_id is None:
                await self.app(scope, receive, send)
                return
        headers = dict(scope["headers"])  # the last of repeated names: only a client's mistake, then FastAPI decides
        state = scope["app"].state
        claims = bearer_claims(state, headers.get(b"authorization"))
        if claims is None:
            await self.app(scope, receive, send)
            return
        body, more = await _read_body(receive)
        response = None
        if not more:  # a disconnect before the whole body: FastAPI's route sees it as it would have
            response = await self._answer(state, claims, sample_id, body, headers.get(b"content-type"))
        if response is None:
            await self.app(scope, _replay(body, more, receive), send)
            return
        await response(scope, receive, send)

    @staticmethod
    async def _answer(state: Any, claims: tuple[int, int], sample_id: int | None, body: bytes,
                      content_type: bytes | None) -> Response | None:
        """The route's response, or None where FastAPI's route must answer (the module's docstring)."""
        if sample_id is None:
            work, args = next_response, ()
        else:
            submission = _submission(body, content_type)
            if submission is None:
                return None
            work, args = submit_response, (sample_id, submission)
        try:
            return await run_in_threadpool(_as_annotator, state, claims, work, *args)
        except DomainError as exc:  # a refusal: the route would say the same (its checks and work are these)
            return domain_response(exc)
        except SQLAlchemyError as exc:  # e.g. the database busy, or a concurrent change: the route tries again
            logger.warning("annotator hot path: %s failed in the database (%s: %s); FastAPI's route answers it",
                           work.__name__, exc.__class__.__name__, getattr(exc, "orig", None) or exc)
            return None
        except Exception:
            logger.exception("annotator hot path: %s failed; FastAPI's route answers it", work.__name__)
            return None


def _submission(body: bytes, content_type: bytes | None) -> SubmissionCreate | None:
    """The body as the route reads it, or None when FastAPI must word the answer (a content type other than JSON,
    a body that is not JSON, or one the schema refuses: its 422 lists the errors)."""
    if content_type is None or content_type.lower() not in _JSON_TYPES:
        return None
    try:
        # As FastAPI does: json.loads, then the model in Python mode (Strict's rules are written for that mode).
        return SubmissionCreate.model_validate(json.loads(body))
    except (ValueError, ValidationError, RecursionError):  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        return None


def _as_annotator(state: Any, claims: tuple[int, int], work: Callable[..., Response], *args: Any) -> Response:
    """`work(state, user, *args)` for the token's user, checked as the route checks it (AuthError,
    PermissionDeniedError), in one thread."""
    user = checked_role(current_principal(state, *claims), Role.annotator)
    return work(state, user, *args)


async def _read_body(receive: Receive) -> tuple[bytes, bool]:
    """(body, True if the client went away before its end)."""
    chunks = []
    while True:
        message = await receive()
        if message["type"] != "http.request":
            return b"".join(chunks), True
        chunks.append(message.get("body", b""))
        if not message.get("more_body", False):
            return b"".join(chunks), False


def _replay(body: bytes, disconnected: bool, receive: Receive) -> Receive:
    """A receive that gives the body read so far once, then what the client sends next."""
    pending = [{"type": "http.disconnect"} if disconnected else
               {"type": "http.request", "body": body, "more_body": False}]
    if disconnected and body:
        pending.insert(0, {"type": "http.request", "body": body, "more_body": True})

    async def replayed() -> dict[str, Any]:
        return pending.pop(0) if pending else await receive()

    return replayed
