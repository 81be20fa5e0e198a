"""The compiled median of the edge reader's kernels."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from spotnav.image.selection import _BRANCHLESS_SELECT_MAX, _median


@given(values=st.lists(st.integers(-5, 5) | st.floats(-1e6, 1e6), min_size=1, max_size=150))
def test_the_compiled_median_is_numpy_s(values: list[float]) -> None:
    # Both selections: without branches up to _BRANCHLESS_SELECT_MAX values, Hoare's past it; ties among them.
    array = np.array(values, dtype=float)
    assert _median(array, np.empty(len(array))) == np.median(array)
    scratch = array.copy()
    assert _median(scratch, scratch) == np.median(array)  # selected in place, as the edge reader's noise is


@pytest.mark.parametrize("count", [_BRANCHLESS_SELECT_MAX, _BRANCHLESS_SELECT_MAX + 1, 2000])
def test_a_median_among_many_equal_values_is_numpy_s(count: int) -> None:
    # Steps between clipped samples: mostly zeros, on both sides of the selection's switch.
    array = np.zeros(count)
    array[::7] = np.arange(len(array[::7])) - 3.0
    assert _median(array, np.empty(count)) == np.median(array)
