"""The joint geometry fit's pieces: the insertion point where known axes meet, the most likely scale of its sigmas."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from spotnav.pose import calibration
from spotnav.pose.calibration import insertion_from_axes
from spotnav.setup.geometry import normalize


@given(
    point=st.tuples(st.floats(-2, 2), st.floats(3, 8), st.floats(15, 22)),
    seed=st.integers(0, 2**16),
)
def test_the_insertion_point_is_where_the_axes_meet(point: tuple[float, float, float], seed: int) -> None:
    rng = np.random.default_rng(seed)
    tips = np.column_stack([rng.uniform(-3, 3, 6), rng.uniform(-3, 3, 6), rng.uniform(2, 7, 6)])
    axes = normalize(tips - np.array(point))
    found, covariance, rms = insertion_from_axes(tips, axes)
    np.testing.assert_allclose(found, point, atol=1e-6)
    assert rms < 1e-6 and np.all(np.diag(covariance) < 1e-10)


def test_the_most_likely_scale_of_the_geometry_s_sigmas() -> None:
    # Frames' misses drawn with their own covariance and a shared geometry error k times the stated one: the
    # scale found is near k (30 shared directions tell it), 1 when the stated one holds, the cap when nothing does.
    rng = np.random.default_rng(7)
    frames, parameters = 40, 30
    own = [np.diag(rng.uniform(0.5, 2.0, 3)) ** 2 for _ in range(frames)]
    gains = [rng.normal(size=(3, parameters)) for _ in range(frames)]
    geometry = np.diag(rng.uniform(0.1, 0.3, parameters) ** 2)
    found = []
    for true_scale in (1.0, 3.0):
        shared = rng.multivariate_normal(np.zeros(parameters), true_scale**2 * geometry)
        misses = [gain @ shared + rng.multivariate_normal(np.zeros(3), c) for gain, c in zip(gains, own, strict=True)]
        found.append(calibration._most_likely_scale(misses, own, gains, geometry))
    assert found[0] < 1.4 and 2.2 < found[1] < 4.0
    misses = [np.full(3, 1e3)] * frames
    assert calibration._most_likely_scale(misses, own, gains, geometry) == 10.0  # refused by calibrate
