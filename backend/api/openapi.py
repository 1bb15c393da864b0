"""The published OpenAPI schema describes what the server sends: every operation lists the error statuses it
can answer, each with the one error body (schemas.errors.ErrorBody), derived from what the route depends on,
so a route added later is documented without doing anything; and request bodies' text refuses NUL characters,
as the server does (PostgreSQL cannot store them).

| status | when | operations |
|---|---|---|
| 401 | no, invalid, expired or revoked token | routes that need a token |
| 403 | role too low, a lease held by someone else | routes that need a token |
| 404 | a named row does not exist | routes with a database session |
| 409 | state conflict, stale lease, concurrent change | routes with a database session |
| 413 | body over `MAX_UPLOAD_BYTES` | routes with a body |
| 422 | parameters or body invalid | routes with parameters or a body |
| 429 | too many failed logins, hashing busy | declared by the route (login) |
| 503 | database busy, job broker unreachable | routes with a database session |
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from fastapi.routing import APIRoute, iter_route_contexts

from backend.api.deps import depends_on, get_current_user, get_session
from backend.schemas.errors import ErrorBody

ERROR_REF = {"$ref": "#/components/schemas/ErrorBody"}
RETRY_AFTER = {"Retry-After": {"description": "Seconds to wait before trying again.", "required": True,
                               "schema": {"type": "string", "pattern": "^[0-9]+$"}}}
DESCRIPTIONS = {
    400: "The body cannot be parsed (a malformed multipart upload); nothing was written.",
    401: "Not authenticated: no, invalid, expired or revoked credentials.",
    403: "Not allowed: the role is too low, or the lease is someone else's.",
    404: "Something the request names does not exist.",
    409: "The current state forbids it (sample state, expired lease, concurrent change); nothing was written.",
    413: "The request body is larger than the server accepts.",
    422: "The parameters or the body are invalid; `errors` says where.",
    429: "Too many attempts; wait for Retry-After seconds.",
    503: "The database is busy or the job broker unreachable; nothing was written, retry after Retry-After seconds.",
}
HEADERS = {429: RETRY_AFTER, 503: RETRY_AFTER}


def error_statuses(route: APIRoute) -> set[int]:
    """The error statuses this operation can answer, from its dependencies, parameters and body."""
    dependant = route.dependant
    statuses = set()
    if depends_on(dependant, get_current_user):
        statuses |= {401, 403}
    # The user's row is read in a session of its own (api.deps.get_current_user): its routes read the database too.
    if depends_on(dependant, get_session) or depends_on(dependant, get_current_user):
        statuses |= {404, 409, 503}  # 409 on reads too: a sample in another state than the route shows
    if route.body_field is not None:
        statuses.add(413)
    if route.body_field is not None or any((dependant.path_params, dependant.query_params, dependant.header_params,
                                            dependant.cookie_params)):
        statuses.add(422)
    statuses |= {int(s) for s in route.responses if str(s).isdigit() and int(s) in DESCRIPTIONS}
    return statuses


NO_NUL = "^[^\\u0000]*$"  # what backend.schemas.base.Strict enforces on every text of a request body


def _refuse_nul(node: Any) -> None:
    """Add NO_NUL to every free-text string schema under `node` (not to enums, constants or formats)."""
    if isinstance(node, list):
        for item in node:
            _refuse_nul(item)
        return
    if not isinstance(node, dict):
        return
    if node.get("type") == "string" and not {"enum", "const", "format"} & set(node):
        if "pattern" not in node:
            node["pattern"] = NO_NUL
        elif {"pattern": NO_NUL} not in node.get("allOf", []):
            node.setdefault("allOf", []).append({"pattern": NO_NUL})
    for key in ("properties", "$defs"):
        for child in node.get(key, {}).values():
            _refuse_nul(child)
    for key in ("items", "anyOf", "allOf", "oneOf", "if", "then", "else", "additionalProperties"):
        if key in node:
            _refuse_nul(node[key])


def _request_components(schema: dict[str, Any]) -> set[str]:
    """Names of the components that request bodies use, directly or through other components."""
    components = schema.get("components", {}).get("schemas", {})
    pending = [op["requestBody"] for methods in schema["paths"].values() for op in methods.values()
               if "requestBody" in op]
    found: set[str] = set()
    while pending:
        node = pending.pop()
        if isinstance(node, dict):
            ref = node.get("$ref", "")
            if ref.startswith("#/components/schemas/") and ref.rsplit("/", 1)[1] not in found:
                found.add(ref.rsplit("/", 1)[1])
                pending.append(components.get(ref.rsplit("/", 1)[1], {}))
            pending.extend(node.values())
        elif isinstance(node, list):
            pending.extend(node)
    return found


def document_errors(schema: dict[str, Any], app: FastAPI) -> None:
    """Add the error responses to every operation of `schema` (in place)."""
    components = schema.setdefault("components", {}).setdefault("schemas", {})
    components.update(ErrorBody.model_json_schema(ref_template="#/components/schemas/{model}").pop("$defs"))
    components["ErrorBody"] = ErrorBody.model_json_schema(ref_template="#/components/schemas/{model}")
    components["ErrorBody"].pop("$defs", None)
    for context in iter_route_contexts(app.routes):
        route = context.original_route
        if not isinstance(route, APIRoute) or not context.include_in_schema:
            continue
        for method in context.methods or ():
            operation = schema["paths"].get(context.path_format, {}).get(method.lower())
            if operation is None:
                continue
            responses = operation.setdefault("responses", {})
            for status in sorted(error_statuses(context)):
                entry = responses.setdefault(str(status), {})
                entry["description"] = entry.get("description") or DESCRIPTIONS[status]
                if entry["description"] == "Validation Error":
                    entry["description"] = DESCRIPTIONS[status]
                entry["content"] = {"application/json": {"schema": ERROR_REF}}
                if status in HEADERS:
                    entry["headers"] = HEADERS[status]
    for unused in ("HTTPValidationError", "ValidationError"):
        components.pop(unused, None)
    for name in _request_components(schema):
        _refuse_nul(components[name])


def install(app: FastAPI) -> None:
    """Wrap `app.openapi` so that the generated (and cached) schema is documented once."""
    generate = app.openapi
    documented: list[int] = []

    def openapi() -> dict[str, Any]:
        schema = generate()
        if not documented or documented[0] != id(schema):
            document_errors(schema, app)
            documented[:] = [id(schema)]
        return schema

    app.openapi = openapi  # type: ignore[method-assign]
