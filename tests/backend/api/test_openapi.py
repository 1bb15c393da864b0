"""The published schema documents every operation's error answers with the body the server sends (issue #13,
defect 3); a route added later gets them without declaring anything. The fuzzing test checks the answers."""

from __future__ import annotations

from fastapi import APIRouter

from backend.api.deps import AnnotatorUser, SessionDep
from backend.models.enums import Role
from backend.schemas.base import Id, Strict

ERROR_REF = {"$ref": "#/components/schemas/ErrorBody"}


class DraftBody(Strict):
    """The body of a route the test adds, as another engineer's new route would be."""

    note_id: Id


def _operations(schema: dict):
    for path, methods in schema["paths"].items():
        for method, operation in methods.items():
            yield method.upper(), path, operation


def test_every_api_operation_documents_its_errors_with_the_error_body(sqlite_env):
    schema = sqlite_env.client.get("/openapi.json").json()
    assert "HTTPValidationError" not in str(schema)  # FastAPI's list form is not what the server sends
    token_routes = 0
    for method, path, operation in _operations(schema):
        responses = operation["responses"]
        for status, response in responses.items():
            if status.startswith(("4", "5")):
                assert response["content"]["application/json"]["schema"] == ERROR_REF, (method, path, status)
        if operation.get("security"):
            token_routes += 1
            assert {"401", "403", "404", "409", "503"} <= set(responses), (method, path, sorted(responses))
        if "requestBody" in operation:
            assert {"413", "422"} <= set(responses), (method, path)
        for status in ("429", "503"):
            if status in responses:
                assert responses[status]["headers"]["Retry-After"]["required"] is True
    assert token_routes >= 30
    login = schema["paths"]["/api/auth/token"]["post"]["responses"]
    assert {"401", "422", "429"} <= set(login)


def test_a_route_added_later_is_documented_without_declaring_anything(sqlite_env):
    router = APIRouter(prefix="/api/drafts")

    @router.post("/{sample_id}")
    def add_draft(sample_id: Id, body: DraftBody, session: SessionDep, user: AnnotatorUser) -> dict:
        return {}

    app = sqlite_env.client.app
    app.include_router(router)
    operation = app.openapi()["paths"]["/api/drafts/{sample_id}"]["post"]
    assert {"401", "403", "404", "409", "413", "422", "503"} <= set(operation["responses"])
    assert operation["responses"]["422"]["content"]["application/json"]["schema"] == ERROR_REF


def test_a_422_body_is_the_documented_error_body(sqlite_env):
    response = sqlite_env.client.post("/api/annotate/prefetch", json={"current_sample_id": "7"},
                                      headers=sqlite_env.headers(Role.annotator))
    assert response.status_code == 422
    body = response.json()
    assert set(body) == {"detail", "errors"} and isinstance(body["detail"], str)
    assert body["errors"][0]["loc"] == ["body", "current_sample_id"]
