from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import small_setup

from spotnav.camera import camera_depth_mm
from spotnav.checks import _depth_of, _fit_spread, blur_shift_px, residuals_px
from spotnav.conefit import edge_angle
from spotnav.detect import SpotEdge


def _edge(width_px: float) -> SpotEdge:
    return SpotEdge(np.zeros((0, 2)), np.zeros(0), width_px, False, 100, 100.0, 0.0, 0.5, 0.005)


def test_a_blur_after_the_encoding_moves_the_edge_by_more_the_wider_it_is() -> None:
    setup = small_setup(1024)
    # The model's own edge (a 60 px spot's soft band, the pixels, the detector's smoothing) is 4.2 px wide.
    widths = (4.0, 5.5, 7.0, 10.0)
    shifts = [blur_shift_px(_edge(width), setup, 60.0, edge_angle(setup)) for width in widths]
    assert shifts[0] == 0.0
    assert 0.0 < shifts[1] < shifts[2] < shifts[3] < widths[3] / 2


def test_a_linear_camera_s_blur_is_a_blur_in_light() -> None:
    # Blurring linear values is blurring light: the midpoint in light stays where it was.
    setup = small_setup(1024)
    linear = replace(setup, camera=replace(setup.camera, response="linear"))
    assert blur_shift_px(_edge(9.0), linear, 60.0, edge_angle(linear)) == pytest.approx(0.0, abs=0.05)


def test_residuals_in_pixels_are_angles_times_distance_over_depth() -> None:
    # A point r mm from its tip and a radians off its cone, at a depth of d mm, is a * r * f / d pixels off.
    camera = small_setup(1024).camera
    rng = np.random.default_rng(3)
    points = rng.uniform(-3.0, 3.0, (20, 3))
    tips = rng.uniform(-1.0, 1.0, (20, 3)) + np.array([0.0, 0.0, 5.0])
    residuals = rng.normal(0.0, 1e-3, 20)
    expected = residuals * np.linalg.norm(points - tips, axis=1) * camera.focal_px / camera_depth_mm(camera, points)
    np.testing.assert_allclose(residuals_px(camera, points, tips, residuals), expected, rtol=1e-12)
    one_tip = residuals_px(camera, points, tips[0], residuals)  # one tip for every point
    np.testing.assert_allclose(one_tip, residuals_px(camera, points, np.tile(tips[0], (20, 1)), residuals), rtol=1e-15)


def test_a_fit_s_spread_is_its_inliers_rms_in_pixels_and_radians() -> None:
    camera = small_setup(1024).camera
    rng = np.random.default_rng(5)
    points = rng.uniform(-3.0, 3.0, (30, 3))
    tip = np.array([0.5, -0.5, 5.0])
    residuals = rng.normal(0.0, 1e-3, 30)
    inliers = rng.random(30) < 0.7
    rms_px, rms_rad, fraction = _fit_spread(points, tip, residuals, inliers, *_depth_of(camera))
    pixels = residuals_px(camera, points, tip, residuals)
    assert rms_px == pytest.approx(np.sqrt(np.mean(pixels[inliers] ** 2)), rel=1e-12)
    assert rms_rad == pytest.approx(np.sqrt(np.mean(residuals[inliers] ** 2)), rel=1e-12)
    assert fraction == pytest.approx(inliers.mean())


def test_residuals_in_pixels_refuse_shapes_that_do_not_match() -> None:
    camera = small_setup(1024).camera
    with pytest.raises(ValueError, match="must match"):
        residuals_px(camera, np.zeros((20, 3)), np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        residuals_px(camera, np.zeros((20, 2)), np.zeros(3), np.zeros(20))
    grid = residuals_px(camera, np.ones((4, 5, 3)), np.zeros(3), 1e-3)  # any leading shape, a scalar residual
    assert grid.shape == (4, 5) and np.all(grid == grid[0, 0])
