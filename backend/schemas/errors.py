"""The body of every error response (backend.api.errors), as the OpenAPI schema publishes it."""

from __future__ import annotations

from pydantic import BaseModel, Field


class ErrorItem(BaseModel):
    loc: list[str | int] = Field(description="Where: 'body', 'path', 'query', then field names and list indices.")
    msg: str
    type: str = Field(description="pydantic's error type, or 'body_unreadable'.")


class ErrorBody(BaseModel):
    detail: str = Field(description="What is wrong, in words a client can act on.")
    errors: list[ErrorItem] | None = Field(default=None, description="422 only: each problem with its location.")
