from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav.geometry import InstrumentPose, angles_between, beam_axes, cone_generators, cone_sphere_curve, normalize
from spotnav.reconstruct import (
    apex_candidates,
    choose_by_insertion,
    correlation_inflation,
    fit_cones,
    fit_ellipse,
    least_squares_covariance,
    robust_sigma,
    sphere_normal,
    triangle_from_ellipse,
)

BETA = np.radians(9.0)
INSERTION = np.array([0.0, 6.0, 20.0])
CENTER = np.array([0.0, 0.0, 12.5])


@pytest.mark.parametrize(
    ("full_axes_px", "alpha_deg", "s1_px", "s2_px", "tolerance"),
    [
        # Table 6.1 -> 6.2: near zero alpha magnifies the rounding of the printed axes.
        ((598.410, 598.418), 0.291, 9.849, 1889.081, (0.005, 0.1, 0.005)),
        ((679.726, 637.629), 20.010, 707.246, 1888.253, (0.0005, 0.005, 0.005)),  # Table 6.3 -> 6.4
        ((540.028, 508.126), 19.539, 550.810, 1509.331, (0.0005, 0.005, 0.005)),  # Table 6.5 -> 6.6
    ],
)
def test_thesis_tables(full_axes_px: tuple, alpha_deg: float, s1_px: float, s2_px: float, tolerance: tuple) -> None:
    # fitEllipse's full axes, unsorted (thesis-notes 2).
    a, b = max(full_axes_px) / 2, min(full_axes_px) / 2
    alpha, s1, s2 = triangle_from_ellipse(a, b, BETA)
    assert np.degrees(alpha) == pytest.approx(alpha_deg, abs=tolerance[0])
    assert s1 == pytest.approx(s1_px, abs=tolerance[1])
    assert s2 == pytest.approx(s2_px, abs=tolerance[2])


def test_fit_ellipse_returns_sorted_semi_axes_and_direction() -> None:
    t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    angle = np.radians(30)
    local = np.column_stack([3.0 * np.cos(t), 2.0 * np.sin(t)])
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    ellipse = fit_ellipse(local @ rotation.T * 100 + [500, 400])
    assert ellipse.semi_major == pytest.approx(300, rel=1e-4)
    assert ellipse.semi_minor == pytest.approx(200, rel=1e-4)
    assert abs(np.dot(ellipse.major_direction, [np.cos(angle), np.sin(angle)])) == pytest.approx(1.0, abs=1e-6)
    with pytest.raises(ValueError, match="at least 5"):
        fit_ellipse(np.zeros((4, 2)))


@settings(max_examples=40, deadline=None)
@given(
    x=st.floats(-3, 3),
    y=st.floats(-3, 3),
    z=st.floats(2, 7),
    tilt=st.floats(0, 0.45),
    azimuth=st.floats(0, 2 * np.pi),
    beta_deg=st.floats(5, 15),
)
def test_exact_on_a_plane(x: float, y: float, z: float, tilt: float, azimuth: float, beta_deg: float) -> None:
    # A cone cut by the plane z = 0 is an exact ellipse: the triangle recovers the apex exactly,
    # to the float32 precision of fitEllipse (its error in alpha grows like the square root
    # of float32's epsilon near alpha = 0).
    beta = np.radians(beta_deg)
    apex = np.array([x, y, z])
    axis = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), -np.cos(tilt)])
    rays = cone_generators(axis, beta, np.linspace(0, 2 * np.pi, 720, endpoint=False))
    points = apex + (-z / rays[:, 2])[:, None] * rays
    candidates = apex_candidates(points, np.array([0.0, 0.0, 1.0]), beta)
    errors = np.linalg.norm(candidates.apexes - apex, axis=1)
    assert errors.min() < 1e-3
    assert np.degrees(candidates.alpha) == pytest.approx(np.degrees(tilt), abs=0.05)
    best = int(np.argmin(errors))
    assert np.dot(candidates.cone_axes[best], axis) == pytest.approx(1.0, abs=1e-6)


@settings(max_examples=40, deadline=None)
@given(x=st.floats(-2.5, 2.5), y=st.floats(-2.5, 2.5), z=st.floats(3, 6))
def test_sphere_curve_within_the_planar_approximation(x: float, y: float, z: float) -> None:
    # On the sphere the thesis's tangent-plane ellipse is an approximation: over the
    # working volume it costs at most 0.026 mm even on an exact contour (0.0259 mm at its
    # worst, the corner (0, 2.5, 6) highest above the retina and nearest the insertion point).
    pose = InstrumentPose.through_insertion([x, y, z], INSERTION)
    points = cone_sphere_curve(pose.tip_in_eye, pose.axis, BETA, CENTER, 12.5, count=1000)
    candidates = apex_candidates(points, sphere_normal(points, CENTER), BETA)
    index, misalignment = choose_by_insertion(candidates, INSERTION)
    assert np.linalg.norm(candidates.apexes[index] - pose.tip_in_eye) < 0.026
    assert misalignment < np.radians(1.0)


def test_choose_by_insertion_takes_the_aligned_candidate() -> None:
    pose = InstrumentPose.through_insertion([2.0, -1.0, 4.0], INSERTION)
    points = cone_sphere_curve(pose.tip_in_eye, pose.axis, BETA, CENTER, 12.5, count=1000)
    candidates = apex_candidates(points, sphere_normal(points, CENTER), BETA)
    index, _ = choose_by_insertion(candidates, INSERTION)
    other = 1 - index
    assert np.linalg.norm(candidates.apexes[index] - pose.tip_in_eye) < np.linalg.norm(
        candidates.apexes[other] - pose.tip_in_eye
    )
    assert np.allclose(np.linalg.norm(candidates.cone_axes, axis=1), 1.0)
    assert normalize(candidates.cone_axes[index]) @ pose.axis > 0.999


def test_height_correction_scales_the_triangle_about_the_ellipse_centre() -> None:
    # A spot that looks 2 % too small (an edge inside the cone) puts the apex 2 % too low;
    # a factor of 1 / 0.98 undoes it exactly on a plane.
    apex, axis = np.array([1.0, 0.5, 5.0]), normalize(np.array([0.2, -0.1, -1.0]))
    rays = cone_generators(axis, BETA, np.linspace(0, 2 * np.pi, 720, endpoint=False))
    points = apex + (-apex[2] / rays[:, 2])[:, None] * rays
    shrunk = points.mean(axis=0) + 0.98 * (points - points.mean(axis=0))
    normal = np.array([0.0, 0.0, 1.0])
    plain = apex_candidates(shrunk, normal, BETA)
    corrected = apex_candidates(shrunk, normal, BETA, height_correction=1 / 0.98)
    assert np.min(np.abs(plain.apexes[:, 2] - apex[2])) > 0.09
    assert np.min(np.linalg.norm(corrected.apexes - apex, axis=1)) < 1e-3
    np.testing.assert_allclose(corrected.plane_normal_in_eye, normal, atol=1e-12)
    assert corrected.s2 == pytest.approx(plain.s2)


@settings(max_examples=25, deadline=None)
@given(
    x=st.floats(-2.5, 2.5),
    y=st.floats(-2.5, 2.5),
    z=st.floats(3, 6),
    roll=st.floats(-np.pi, np.pi),
    beams=st.sampled_from([1, 3]),
    light=st.sampled_from([0.0, 0.02, 0.1]),
)
def test_fit_cones_recovers_the_pose_from_exact_curves(
    x: float, y: float, z: float, roll: float, beams: int, light: float
) -> None:
    # Points on the exact cone-sphere curves (each cone widened by a light of radius `light`: its apex
    # lies light / tan(beta) behind the tip), a start 0.1 mm off: the fit lands on the truth.
    tilt = np.radians(15.0)
    pose = InstrumentPose.through_insertion([x, y, z], INSERTION)
    axes = beam_axes(pose.axis, beams, tilt, roll if beams == 3 else 0.0)
    behind = light / np.tan(BETA)
    curves = [cone_sphere_curve(pose.tip_in_eye - behind * a, a, BETA, CENTER, 12.5, count=200) for a in axes]
    fit = fit_cones(
        curves,
        list(range(beams)),
        BETA,
        beam_count=beams,
        tilt=tilt,
        tip_in_eye=pose.tip_in_eye + np.array([0.05, -0.05, 0.08]),
        axis=pose.axis,
        roll=(roll + 0.05) if beams == 3 else 0.0,
        insertion_in_eye=INSERTION,
        light_radius=light,
    )
    np.testing.assert_allclose(fit.tip_in_eye, pose.tip_in_eye, atol=1e-6)
    np.testing.assert_allclose(fit.axis, pose.axis, atol=1e-6)
    assert fit.inliers.all()
    assert fit.tip_sigma_mm < 1e-6


def test_fit_cones_frees_the_axis_and_reports_the_edge_model_uncertainty() -> None:
    pose = InstrumentPose([1.0, -0.5, 4.5], [0.2, -0.1, -1.0])  # not through the insertion point
    curve = cone_sphere_curve(pose.tip_in_eye, pose.axis, BETA, CENTER, 12.5, count=300)
    rng = np.random.default_rng(0)
    noisy = curve + rng.normal(0.0, 0.001, curve.shape)
    common = {"beam_count": 1, "tilt": 0.0, "tip_in_eye": pose.tip_in_eye + 0.05, "axis": pose.axis}
    free = fit_cones([noisy], [0], BETA, **common)
    assert np.linalg.norm(free.tip_in_eye - pose.tip_in_eye) < 3 * free.tip_sigma_mm + 1e-4
    assert angles_between(free.axis, pose.axis) < np.radians(1.0)
    with_model = fit_cones([noisy], [0], BETA, edge_sigma=np.radians(0.01), **common)
    assert with_model.tip_sigma_mm > free.tip_sigma_mm


def test_correlation_inflation_of_known_sequences() -> None:
    groups = np.zeros(40, dtype=np.int64)
    assert correlation_inflation(np.tile([1.0, -1.0], 20), groups) == 1.0  # anti-correlated: no inflation
    assert correlation_inflation(np.linspace(-1, 1, 40), groups) == pytest.approx(19.0)  # rho capped at 0.9
    # Neighbours are taken within a group only: two groups, each alternating about its own mean.
    two = np.concatenate([np.tile([5.0, 3.0], 10), np.tile([-2.0, -4.0], 10)])
    assert correlation_inflation(two, np.repeat([0, 1], 20)) == 1.0
    assert correlation_inflation(np.empty(0), np.empty(0, dtype=np.int64)) == 1.0


@given(seed=st.integers(0, 2**31))
def test_least_squares_covariance_is_the_textbook_formula(seed: int) -> None:
    rng = np.random.default_rng(seed)
    jacobian, residuals = rng.normal(size=(50, 4)), rng.normal(size=50)
    groups = np.repeat(np.arange(5), 10)
    covariance, normal_inverse = least_squares_covariance(jacobian, residuals, groups)
    np.testing.assert_allclose(normal_inverse, np.linalg.inv(jacobian.T @ jacobian), rtol=1e-9)
    expected = np.sum(residuals**2) / 46 * correlation_inflation(residuals, groups) * normal_inverse
    np.testing.assert_allclose(covariance, expected, rtol=1e-12)


def test_robust_sigma_ignores_outliers() -> None:
    values = np.random.default_rng(3).normal(2.0, 0.5, 20001)
    values[:2000] = 1e6  # 10 % gross outliers
    # 10 % of the values off the scale widen the robust sigma by 14 % (0.5 sigma: 1.14 x 0.5); a plain
    # standard deviation would be 3e5.
    assert robust_sigma(values, True) == pytest.approx(0.5 * 1.14, rel=0.02)
    assert robust_sigma(values - np.median(values), False) == pytest.approx(robust_sigma(values, True))
