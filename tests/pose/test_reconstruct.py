from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from spotnav.pose.reconstruct import (
    apex_candidates,
    choose_by_insertion,
    fit_ellipse,
    sphere_normal,
    triangle_from_ellipse,
)
from spotnav.setup.geometry import InstrumentPose, cone_generators, cone_sphere_curve, normalize

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
    with pytest.raises(ValueError, match="finite"):
        fit_ellipse(np.array([[1.0, np.nan]] * 6))


@pytest.mark.parametrize(
    "points",
    [
        np.column_stack([np.arange(10.0), 2.0 * np.arange(10.0)]),  # a line
        np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0], [4.0, 4.0], [1.0, 1.0]]),  # a line, repeated points
        np.zeros((6, 2)),  # one point
    ],
)
def test_fit_ellipse_refuses_points_no_ellipse_fits(points: np.ndarray) -> None:
    with pytest.raises(ValueError, match="no ellipse fits"):
        fit_ellipse(points)


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
    # to the double precision of the fit (its error in alpha grows like the square root of
    # float64's epsilon near alpha = 0: 1e-8 rad, 1e-7 mm at 7 mm; float32's was 3e-3 mm).
    beta = np.radians(beta_deg)
    apex = np.array([x, y, z])
    axis = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), -np.cos(tilt)])
    rays = cone_generators(axis, beta, np.linspace(0, 2 * np.pi, 720, endpoint=False))
    points = apex + (-z / rays[:, 2])[:, None] * rays
    candidates = apex_candidates(points, np.array([0.0, 0.0, 1.0]), beta)
    errors = np.linalg.norm(candidates.apexes - apex, axis=1)
    assert errors.min() < 1e-5
    assert np.degrees(candidates.alpha) == pytest.approx(np.degrees(tilt), abs=1e-4)
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


@given(
    centre=st.tuples(st.floats(-50, 50), st.floats(-50, 50)),
    semi=st.tuples(st.floats(5, 60), st.floats(0.3, 1.0)),
    angle=st.floats(0, np.pi),
    noise=st.floats(0, 0.02),
)
# Exact points whose ellipse's eigenvalue rounding pairs with another as complex conjugates (hypothesis found it).
@example(centre=(0.5168604076242932, 0.75), semi=(5.0, 0.5168604076242932), angle=1.375, noise=0.0)
def test_fit_ellipse_agrees_with_opencv(centre: tuple, semi: tuple, angle: float, noise: float) -> None:
    # The double-precision direct fit is OpenCV's fitEllipseDirect, to its single precision.
    major, minor = semi[0], semi[0] * semi[1]
    t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    points = np.column_stack([major * np.cos(t), minor * np.sin(t)]) @ rotation.T + centre
    points += np.random.default_rng(0).normal(0, noise * minor, points.shape)  # noise: of the minor axis
    ours = fit_ellipse(points)
    (cx, cy), axes, _ = cv2.fitEllipseDirect(points.astype(np.float32))
    assert ours.center == pytest.approx([cx, cy], abs=1e-3 * major)
    assert [ours.semi_major, ours.semi_minor] == pytest.approx(sorted(np.array(axes) / 2, reverse=True), rel=1e-3)
    assert ours.semi_major == pytest.approx(major, rel=0.05) and ours.semi_minor == pytest.approx(minor, rel=0.05)


def test_a_contour_no_ellipse_fits_is_refused_with_its_reason() -> None:
    line = np.column_stack([np.linspace(-1.0, 1.0, 12), np.zeros(12), np.zeros(12)])  # collinear: no ellipse
    refused = apex_candidates(line, np.array([0.0, 0.0, 1.0]), BETA)
    assert (refused.ok, refused.status, refused.detail) == (False, "unreliable", "no ellipse fits the contour")
    assert np.isnan(refused.apexes).all() and np.isnan(refused.alpha)
    assert apex_candidates(line[:4], np.array([0.0, 0.0, 1.0]), BETA).status == "unreliable"
