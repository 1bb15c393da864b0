from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from backend.services.captures.masks import decode_png, decode_rle, encode_png, encode_rle
from backend.services.errors import InvalidInputError


@settings(max_examples=50, deadline=None)
@given(arrays(bool, st.tuples(st.integers(1, 12), st.integers(1, 12))))
def test_rle_and_png_round_trip(mask):
    h, w = mask.shape
    assert np.array_equal(decode_rle(encode_rle(mask), w, h), mask)
    assert np.array_equal(decode_png(encode_png(mask)), mask)


def test_rle_starts_with_background():
    assert encode_rle(np.array([[True, False]])) == [0, 1, 1]


def test_rle_must_cover_the_image():
    with pytest.raises(InvalidInputError, match="covers 3 pixels"):
        decode_rle([1, 2], 2, 2)
