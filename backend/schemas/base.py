"""Shared field types and the base classes of request and response models."""

from __future__ import annotations

import types
import typing
from enum import Enum
from functools import cache
from itertools import repeat
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator

Finite = Annotated[float, Field(allow_inf_nan=False)]
Pixel = Annotated[float, Field(allow_inf_nan=False, ge=-1e6, le=1e6)]
# Every database id, in bodies and as a path parameter (`sample_id: Id`): the primary keys are INTEGER, whose
# range on PostgreSQL is 32-bit (beyond it "integer out of range"; beyond 2**63 SQLite's integers overflow, a
# 500), so larger ids are a 422 before any query, the same on both databases.
MAX_ID = 2**31 - 1
Id = Annotated[int, Field(ge=1, le=MAX_ID)]


class Strict(BaseModel):
    """Requests: unknown fields are errors, so typos do not pass silently; and no coercion (`"x": "12"`,
    `"keypoint": true` and `"is_active": 1` are 422, not stored as 12, 1 and True).

    FastAPI validates the parsed JSON in Python mode, where strict enums would want Enum instances: an enum
    field takes its values as strings (and nothing else), converted here. JSON has one number type and JSON
    Schema counts `3.0` as an integer, so an integer field takes a float without a fractional part (never
    `true` or `"3"`)."""

    model_config = ConfigDict(extra="forbid", strict=True)

    @field_validator("*", mode="before")
    @classmethod
    def _from_json_values(cls, value: Any, info: ValidationInfo) -> Any:
        if type(value) is str:
            _no_nul(value)
        kind = _field_kinds(cls).get(info.field_name or "")
        if kind is None:
            return value
        if kind is int:
            return _whole(value)
        if kind is list:  # a mask's run lengths can be millions long: look for floats at C speed first
            if isinstance(value, list) and any(map(isinstance, value, repeat(float))):
                return [_whole(v) for v in value]
            return value
        return enum_from_json(kind, value)


def _no_nul(value: str) -> None:
    if "\x00" in value:  # PostgreSQL cannot store it (a 500 there, not a 422)
        raise ValueError("text must not contain NUL (0x00) characters")


def enum_from_json(kind: type[Enum], value: Any) -> Any:
    """A JSON string as the member of `kind` it names (what Strict does for an enum field); anything but a string
    is left to the field's own (strict) validation."""
    if type(value) is not str:
        return value
    _no_nul(value)  # (Strict checked it already; a model's own validator calling this may not have)
    try:
        return kind(value)
    except ValueError:
        allowed = ", ".join(repr(member.value) for member in kind)
        raise ValueError(f"{value!r} is not one of {allowed}") from None


def whole(value: Any) -> Any:
    """A float without a fractional part as an int (JSON Schema counts `3.0` as an integer); else unchanged
    (a string is checked for NUL, as Strict does)."""
    if type(value) is float:
        return int(value) if value.is_integer() else value
    if type(value) is str:
        _no_nul(value)
    return value


_whole = whole


@cache
def _field_kinds(model: type[BaseModel]) -> dict[str, Any]:
    """Field name -> its Enum type, `int` or `list` (of int), plain or optional, for the fields that need it."""
    found: dict[str, Any] = {}
    for name, field in model.model_fields.items():
        union = typing.get_origin(field.annotation) in (typing.Union, types.UnionType)
        for arg in typing.get_args(field.annotation) if union else (field.annotation,):
            if isinstance(arg, type) and issubclass(arg, Enum):
                found[name] = arg
            elif _is_int(arg):
                found[name] = int
            elif typing.get_origin(arg) is list and _is_int(typing.get_args(arg)[0]):
                found[name] = list
    return found


def _is_int(annotation: Any) -> bool:
    return annotation is int or (typing.get_origin(annotation) is Annotated and typing.get_args(annotation)[0] is int)


class Public(BaseModel):
    model_config = ConfigDict(from_attributes=True)
