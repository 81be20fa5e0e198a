from __future__ import annotations

import numpy as np
import pytest

from spotnav.optics.edgeblur import (
    frame_blur_for_width,
    frame_blur_shift,
    full_width_at_half_maximum,
    response_curve,
    seen_edge,
)


def test_the_full_width_at_half_maximum_of_a_gaussian() -> None:
    x = np.arange(-40.0, 40.5, 0.5)
    counted, width = full_width_at_half_maximum(np.exp(-0.5 * (x / 3.0) ** 2))
    assert width * 0.5 == pytest.approx(np.sqrt(8.0 * np.log(2.0)) * 3.0, rel=0.01)
    assert counted == 15.0  # samples within 3.53 px of the peak, every 0.5 px


@pytest.mark.parametrize("blur_px", [0.5, 1.0, 2.0])
def test_a_width_gives_back_the_blur_that_made_it(blur_px: float) -> None:
    grid = response_curve("srgb")
    width, _ = seen_edge(0.5, 0.005, 3.0, blur_px, *grid)
    assert frame_blur_for_width(0.5, 0.005, 3.0, width, *grid) == pytest.approx(blur_px, abs=0.02)
    assert frame_blur_for_width(0.5, 0.005, 3.0, seen_edge(0.5, 0.005, 3.0, 0.0, *grid)[0] - 0.1, *grid) == 0.0


def test_a_blur_of_an_srgb_frame_shrinks_a_bright_spot_and_not_a_linear_one() -> None:
    # sRGB bends the light before the blur averages it: the half-light crossing moves inward, the more the
    # wider the blur and the brighter the spot over its background. Blurring linear codes is blurring light.
    srgb, linear = response_curve("srgb"), response_curve("linear")
    shifts = [frame_blur_shift(0.5, 0.005, 3.0, blur, *srgb) for blur in (0.0, 0.5, 1.0, 2.0)]
    assert shifts[0] == 0.0 and 0.0 > shifts[1] > shifts[2] > shifts[3] > -1.0
    assert frame_blur_shift(0.9, 0.1, 3.0, 1.0, *srgb) > shifts[2]
    assert frame_blur_shift(0.5, 0.005, 3.0, 2.0, *linear) == pytest.approx(0.0, abs=0.01)
    assert frame_blur_shift(0.5, 0.005, 3.0, np.inf, *srgb) == -np.inf
