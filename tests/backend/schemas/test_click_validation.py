"""ClickIn runs Strict's JSON conversions on three of its fields only (a submission holds ~50 clicks): it must
accept and refuse exactly what the generic Strict model with the same fields does, with the same errors."""

from __future__ import annotations

import pytest
from pydantic import ValidationError, model_validator

from backend.models.enums import Visibility
from backend.schemas.base import Id, Pixel, Strict
from backend.schemas.tasks import ClickIn


class ReferenceClick(Strict):
    """ClickIn's fields and rule with the generic validator of every field (the obviously-correct reference)."""

    view_id: Id
    keypoint: int = ClickIn.model_fields["keypoint"]
    x: Pixel | None = None
    y: Pixel | None = None
    visibility: Visibility = Visibility.visible
    from_proposal: bool = False

    @model_validator(mode="after")
    def _rule(self) -> ReferenceClick:
        return ClickIn._position_matches_visibility(self)  # type: ignore[arg-type]


CASES = [
    {"view_id": 1, "keypoint": 2, "x": 1.5, "y": 2},
    {"view_id": 1.0, "keypoint": 2.0, "x": 1, "y": 1},
    {"view_id": 1.5, "keypoint": 2, "x": 1, "y": 1},
    {"view_id": "1", "keypoint": 2, "x": 1, "y": 1},
    {"view_id": "1\x00", "keypoint": 2, "x": 1, "y": 1},
    {"view_id": None, "keypoint": 2, "x": 1, "y": 1},
    {"view_id": 0, "keypoint": 2, "x": 1, "y": 1},
    {"view_id": 2**40, "keypoint": 2, "x": 1, "y": 1},
    {"view_id": 1, "keypoint": True, "x": 1, "y": 1},
    {"view_id": 1, "keypoint": "4", "x": 1, "y": 1},
    {"view_id": 1, "keypoint": 21.0, "x": 1, "y": 1},
    {"view_id": 1, "keypoint": 2, "x": "12", "y": 1},
    {"view_id": 1, "keypoint": 2, "x": True, "y": 1},
    {"view_id": 1, "keypoint": 2, "x": float("nan"), "y": 1},
    {"view_id": 1, "keypoint": 2, "x": 1e7, "y": 1},
    {"view_id": 1, "keypoint": 2, "x": 1, "y": 1, "visibility": "occluded"},
    {"view_id": 1, "keypoint": 2, "x": 1, "y": 1, "visibility": "seen"},
    {"view_id": 1, "keypoint": 2, "x": 1, "y": 1, "visibility": "vis\x00"},
    {"view_id": 1, "keypoint": 2, "x": 1, "y": 1, "visibility": 1},
    {"view_id": 1, "keypoint": 2, "x": 1, "y": 1, "visibility": None},
    {"view_id": 1, "keypoint": 2, "visibility": "not_annotated"},
    {"view_id": 1, "keypoint": 2, "x": 1, "visibility": "not_annotated"},
    {"view_id": 1, "keypoint": 2, "x": 1.0, "visibility": "occluded"},
    {"view_id": 1, "keypoint": 2, "x": 1, "y": 1, "from_proposal": 1},
    {"view_id": 1, "keypoint": 2, "x": 1, "y": 1, "from_proposal": True},
    {"view_id": 1, "keypoint": 2, "x": 1, "y": 1, "colour": "red"},
    "not an object",
]


def _outcome(model: type[Strict], data: object) -> object:
    try:
        return model.model_validate(data).model_dump()
    except ValidationError as exc:
        return [(e["loc"], e["msg"].replace(model.__name__, "the model"), e["type"]) for e in exc.errors()]


@pytest.mark.parametrize("data", CASES, ids=range(len(CASES)))
def test_a_click_validates_as_the_generic_strict_model_does(data):
    assert _outcome(ClickIn, data) == _outcome(ReferenceClick, data)
