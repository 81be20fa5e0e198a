from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from spotnav.files.numbers import json_floats, parse_float, parse_int

NUMBER_TEXT = st.text(alphabet="0123456789_.eE+- \t\ninfatyINFATY\u0661\u00a0x,", max_size=12)


@given(NUMBER_TEXT)
def test_a_number_is_read_where_float_reads_it(text: str) -> None:
    number = parse_float(text)
    if number is None:
        with pytest.raises(ValueError):
            float(text)
    else:
        assert number == float(text) or (math.isnan(number) and math.isnan(float(text)))


@given(NUMBER_TEXT)
def test_a_whole_number_is_read_where_int_reads_it(text: str) -> None:
    number = parse_int(text)
    if number is None:
        with pytest.raises(ValueError):
            int(text)
    else:
        assert number == int(text)


@pytest.mark.parametrize(
    "text",
    ["[1, 2.5, -3]", '["1_000", " 2 ", null]', "[[1, 2], [3, 4]]", "[]", "4", '"inf"', "[true, 0, 1e308]"],
)
def test_a_json_value_is_read_as_numpy_reads_it(text: str) -> None:
    value = json.loads(text)
    np.testing.assert_array_equal(json_floats(value), np.array(value, dtype=float))


@pytest.mark.parametrize("text", ['["one", 2, 3]', "[[1, 2], [3]]", "[1, [2]]", '{"x": 1}', "[{}, 1, 2]", '"word"'])
def test_a_json_value_numpy_refuses_is_none(text: str) -> None:
    value = json.loads(text)
    assert json_floats(value) is None
    with pytest.raises((ValueError, TypeError)):
        np.array(value, dtype=float)
