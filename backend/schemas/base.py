"""Shared field types and the base classes of request and response models."""

from __future__ import annotations

import typing
from enum import Enum
from functools import cache
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator

Finite = Annotated[float, Field(allow_inf_nan=False)]
Pixel = Annotated[float, Field(allow_inf_nan=False, ge=-1e6, le=1e6)]
# Every database id, in bodies and as a path parameter (`sample_id: Id`): beyond 2**62 SQLite's 64-bit
# integers would overflow (a 500), so such ids are a 422 before any query.
Id = Annotated[int, Field(ge=1, le=2**62)]


class Strict(BaseModel):
    """Requests: unknown fields are errors, so typos do not pass silently; and no coercion (`"x": "12"`,
    `"keypoint": true` and `"is_active": 1` are 422, not stored as 12, 1 and True).

    FastAPI validates the parsed JSON in Python mode, where strict enums would want Enum instances: an enum
    field takes its values as strings (and nothing else), converted here."""

    model_config = ConfigDict(extra="forbid", strict=True)

    @field_validator("*", mode="before")
    @classmethod
    def _enum_from_value(cls, value: Any, info: ValidationInfo) -> Any:
        enum = _enum_fields(cls).get(info.field_name or "")
        if enum is None or not isinstance(value, str):
            return value
        try:
            return enum(value)
        except ValueError:
            allowed = ", ".join(repr(member.value) for member in enum)
            raise ValueError(f"{value!r} is not one of {allowed}") from None


@cache
def _enum_fields(model: type[BaseModel]) -> dict[str, type[Enum]]:
    """Field name -> its Enum type (plain or optional) for a model's enum fields."""
    found = {}
    for name, field in model.model_fields.items():
        for arg in typing.get_args(field.annotation) or (field.annotation,):
            if isinstance(arg, type) and issubclass(arg, Enum):
                found[name] = arg
    return found


class Public(BaseModel):
    model_config = ConfigDict(from_attributes=True)
