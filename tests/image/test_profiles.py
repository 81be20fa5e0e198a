"""The edge reader's compiled profiles along rays."""

from __future__ import annotations

import cv2
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from spotnav.image.profiles import _SMOOTHING, _smooth


@given(seed=st.integers(0, 2**31), length=st.integers(9, 80))
def test_compiled_smoothing_is_opencvs_reflected_gaussian(seed: int, length: int) -> None:
    values = np.random.default_rng(seed).normal(size=length)
    expected = cv2.GaussianBlur(values[None, :], (17, 1), 2.0, borderType=cv2.BORDER_REFLECT)[0]
    padded, out = np.empty(length + len(_SMOOTHING)), np.empty(length)
    np.testing.assert_allclose(_smooth(values, _SMOOTHING, 0, length, padded, out), expected, atol=1e-12)
    # Only samples 3 .. length - 3, into the same buffers: every padded sample it reads is its own (a stale one
    # would be NaN).
    padded[:] = np.nan
    part = _smooth(values, _SMOOTHING, 3, length - 2, padded, out)
    np.testing.assert_allclose(part[3 : length - 2], expected[3 : length - 2], atol=1e-12)
    assert np.isnan(part[:3]).all() and np.isnan(part[length - 2 :]).all()
    for start, stop in ((5, -2), (length, length + 4), (length + 3, length + 9), (-4, 0)):  # nothing to compute
        assert np.isnan(_smooth(values, _SMOOTHING, start, stop, padded, out)).all()
