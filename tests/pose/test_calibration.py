"""The joint geometry fit's pieces: the insertion point where known axes meet, the most likely scale of its sigmas,
when a held-out check misses."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from spotnav.pose import calibration
from spotnav.pose.calibration import HeldOut, insertion_from_axes
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


def test_a_held_out_check_misses_on_a_frame_over_5_sigma_or_under_two_thirds_within_3() -> None:
    names = tuple(f"f{i}" for i in range(6))
    sigma = (0.01,) * 6
    within = HeldOut(4, names, ("ok",) * 6, (0.01, 0.02, 0.03, 0.01, 0.02, 0.05), sigma)
    assert within.answered == 6 and within.coverage() == 1.0 and not within.misses()
    np.testing.assert_allclose(within.sigmas()[:2], [1 / np.sqrt(3), 2 / np.sqrt(3)])
    one_far = replace(within, errors_mm=(0.01, 0.02, 0.03, 0.01, 0.02, 0.09))  # 5.2 sigma (3-D)
    assert one_far.coverage() == 5 / 6 and one_far.misses()
    spread = replace(within, errors_mm=(0.06, 0.06, 0.06, 0.01, 0.02, 0.03))  # half within 3 sigma, none over 5
    assert spread.coverage() == 0.5 and spread.misses()
    refused = replace(within, statuses=("ok", "ok", "uncalibrated", "uncalibrated", "refused", "ok"))
    assert refused.answered == 3 and refused.coverage() == 1.0 and not refused.misses()
    mostly_refused = replace(refused, statuses=("ok", "ok", "uncalibrated", "uncalibrated", "refused", "refused"))
    assert mostly_refused.misses()
