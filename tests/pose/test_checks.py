from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest
from conftest import small_setup

from spotnav.experiments.scenes import with_true_edge
from spotnav.image.rays import SpotEdge
from spotnav.optics.camera import camera_depth_mm
from spotnav.optics.light import edge_angle
from spotnav.optics.render import Renderer
from spotnav.pose.checks import FIT_RATIO_EXPLAINED, MAX_FIT_RATIO, _depth_of, _fit_spread, blur_shift_px, residuals_px
from spotnav.pose.estimate import within_sigmas
from spotnav.pose.localize import localize
from spotnav.setup.config import Setup, setup_from_toml
from spotnav.setup.examples import EXAMPLE_SETUP
from spotnav.setup.geometry import InstrumentPose, edge_angle_of_blend


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
    spots, pixels = np.zeros(30, dtype=np.int64), rng.uniform(0.0, 1024.0, (30, 2))
    rms_px, rms_rad, fraction, _ = _fit_spread(points, tip, residuals, inliers, spots, pixels, *_depth_of(camera))
    pixels = residuals_px(camera, points, tip, residuals)
    assert rms_px == pytest.approx(np.sqrt(np.mean(pixels[inliers] ** 2)), rel=1e-12)
    assert rms_rad == pytest.approx(np.sqrt(np.mean(residuals[inliers] ** 2)), rel=1e-12)
    assert fraction == pytest.approx(inliers.mean())


def test_the_noise_a_fit_s_residuals_show_is_their_scatter_and_not_a_slow_bend() -> None:
    """White residuals: the noise explains all of them (ratio about 1), and so it does residuals smoothed over a
    few points (a blurred frame); a slow bend of the edge (a model that does not fit) adds to the RMS and not to
    the noise; too few points tell no noise."""
    camera = small_setup(1024).camera
    rng = np.random.default_rng(6)
    count = 2 * 256
    points = rng.uniform(-3.0, 3.0, (count, 3))
    tip = np.array([0.5, -0.5, 5.0])
    spots = np.repeat(np.arange(2), 256)
    angles = np.tile(np.linspace(0.0, 2.0 * np.pi, 256, endpoint=False), 2)
    centres = np.repeat([[300.0, 400.0], [600.0, 500.0]], 256, axis=0)
    pixels = centres + 80.0 * np.column_stack([np.cos(angles), np.sin(angles)])
    white = rng.normal(0.0, 1e-4, count)
    inliers = np.ones(count, dtype=bool)
    camera_terms = _depth_of(camera)
    _, rms, _, noise = _fit_spread(points, tip, white, inliers, spots, pixels, *camera_terms)
    assert noise == pytest.approx(1e-4, rel=0.1) and rms / noise == pytest.approx(1.0, abs=0.1)
    smooth = np.concatenate([np.convolve(np.tile(white[:256], 3), np.ones(5) / 5, "same")[256:512]] * 2)
    _, rms, _, noise = _fit_spread(points, tip, smooth, inliers, spots, pixels, *camera_terms)
    # Smoothed over 5 of 256 points, the noise keeps a fifth of its power in a fifth of the bins: the series's
    # 13 terms take some 13 / 51 of it, and the ratio is about 1 / sqrt(1 - 0.25) = 1.15.
    assert 1.0 < rms / noise < 1.25
    bent = white + 5e-4 * np.cos(2.0 * angles)  # an ellipse of the wrong shape
    _, rms, _, noise = _fit_spread(points, tip, bent, inliers, spots, pixels, *camera_terms)
    assert noise == pytest.approx(1e-4, rel=0.15) and rms / noise > 3.0
    few = np.arange(count) < 30
    assert np.isnan(_fit_spread(points, tip, white, few, spots, pixels, *camera_terms)[3])


def test_residuals_in_pixels_refuse_shapes_that_do_not_match() -> None:
    camera = small_setup(1024).camera
    with pytest.raises(ValueError, match="must match"):
        residuals_px(camera, np.zeros((20, 3)), np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        residuals_px(camera, np.zeros((20, 2)), np.zeros(3), np.zeros(20))
    grid = residuals_px(camera, np.ones((4, 5, 3)), np.zeros(3), 1e-3)  # any leading shape, a scalar residual
    assert grid.shape == (4, 5) and np.all(grid == grid[0, 0])


def _three_beams(half_angle_deg: float) -> Setup:
    """512 px, three beams of this half-angle, Blender's blend; the localizer's edge model that beam's."""
    setup = small_setup(512, blend=0.15)
    edge = np.degrees(edge_angle_of_blend(np.radians(half_angle_deg), 0.15))
    instrument = replace(setup.instrument, beam_count=3, beam_half_angle_deg=half_angle_deg, edge_half_angle_deg=edge)
    return replace(setup, instrument=instrument)


def test_three_beams_wider_than_the_setup_says_are_refused_as_a_mismatch_that_names_the_edge_angle() -> None:
    """The light 0.5 deg wider than the setup's: without the test, ok and some 0.1 mm off at 20 sigma; with it,
    ``mismatch``, the edge angle the frame shows and the command that calibrates it. The light the setup says
    fits its frame: ``ok``, residuals the noise explains."""
    setup, world = _three_beams(9.0), _three_beams(9.5)
    pose = InstrumentPose.through_insertion(np.array([0.5, 0.5, 5.0]), setup.instrument.insertion_in_eye)
    wrong = localize(Renderer(world).render(pose, seed=3), setup, "precise")
    assert wrong.status == "mismatch" and wrong.fit_ratio > MAX_FIT_RATIO
    assert "spotnav calibrate --fit edge-angle" in wrong.detail
    shown = re.search(r"its edge fits at ([0-9.]+) deg where the setup says ([0-9.]+)", wrong.detail)
    assert shown is not None
    assert float(shown[1]) == pytest.approx(world.instrument.edge_half_angle_deg, abs=0.05)
    assert float(shown[2]) == pytest.approx(setup.instrument.edge_half_angle_deg, abs=0.005)
    right = localize(Renderer(setup).render(pose, seed=3), setup, "precise")
    assert right.ok and right.fit_ratio < FIT_RATIO_EXPLAINED
    assert np.linalg.norm(right.pose()[0] - pose.tip_in_eye) < 3 * right.sigma_mm


def _six_degrees(texture: str = "retina") -> tuple[Setup, Setup]:
    """512 px, one 6 deg beam, 1 W, Blender's blend (the sweep's smallest design point): the world and the setup that
    knows it exactly (its edge model the world's)."""
    world = small_setup(512, blend=0.15, texture=texture)
    world = replace(world, instrument=replace(world.instrument, beam_half_angle_deg=6.0))
    edge = np.degrees(edge_angle_of_blend(world.instrument.beam_half_angle, 0.15))
    return world, replace(world, instrument=replace(world.instrument, edge_half_angle_deg=edge))


# Spots 0.25-0.3 mm across on the retina, 8-11 px in radius: vessels under their edge bent it by harmonics the fit
# test took for a misfit (fit_ratio 2.8-3.2 at (2, 0, 3), refused ``mismatch``: calibrate the geometry).
_SMALL_SPOT_TIPS = [(2.0, 0.0, 3.0), (2.0, 0.0, 2.5), (1.0, 1.0, 2.5), (-1.0, -1.7, 3.0)]


@pytest.mark.parametrize("seed", [0, 1])
def test_an_exact_world_s_small_spots_are_not_a_mismatch(seed: int) -> None:
    """The world the setup says, spots 8-11 px in radius: never ``mismatch``; the residuals are what the noise (the
    fundus's bends among it) explains; on a flat fundus as before, the noise alone."""
    world, setup = _six_degrees()
    flat_world, flat_setup = _six_degrees("flat")
    for tip in _SMALL_SPOT_TIPS:
        pose = InstrumentPose.through_insertion(np.array(tip), setup.instrument.insertion_in_eye)
        estimate = localize(Renderer(world).render(pose, seed=seed), setup, "precise")
        assert estimate.status != "mismatch", (tip, estimate)
        assert estimate.fit_ratio < FIT_RATIO_EXPLAINED, (tip, estimate)
        flat = localize(Renderer(flat_world).render(pose, seed=seed), flat_setup, "precise")
        assert flat.ok and flat.fit_ratio == pytest.approx(1.0, abs=0.2), (tip, flat)
        assert np.linalg.norm(flat.pose()[0] - pose.tip_in_eye) < 3 * flat.sigma_mm


def test_one_beam_s_excess_that_widens_sigma_too_far_is_unreliable_and_says_both_causes() -> None:
    """One beam, residuals 1.6 times their noise from the vessels under a 0.6 mm spot's edge in an exact world: the
    widened sigma (0.040 mm) refuses it, as ``unreliable`` that names the fundus and the setup, not a ``mismatch``
    that tells the user to calibrate a geometry that is exact (the sweep's frame that did)."""
    world, setup = _six_degrees()
    pose = InstrumentPose.through_insertion(np.array([2.0, 0.0, 6.0]), setup.instrument.insertion_in_eye)
    estimate = localize(Renderer(world).render(pose, seed=2529356301), setup, "precise")
    assert estimate.status == "unreliable", estimate
    assert FIT_RATIO_EXPLAINED < estimate.fit_ratio < MAX_FIT_RATIO
    assert "the fundus under the edge" in estimate.detail and "spotnav calibrate" in estimate.detail


def _first_try_frame_3(texture: str) -> tuple[float, float]:
    """The README's first try's helix frame 3 (its tip, noise seed 3) at 512 px, read by the setup that knows the world
    exactly: the tip's error and ``sigma_mm``, mm."""
    world = setup_from_toml(EXAMPLE_SETUP.replace("_px = 5000", "_px = 512"))
    world = replace(world, render=replace(world.render, texture=texture))
    tip = np.array([1.651774, 1.205726, 3.181965])
    pose = InstrumentPose.through_insertion(tip, world.instrument.insertion_in_eye)
    estimate = localize(Renderer(world).render(pose, seed=3), with_true_edge(world), "precise")
    assert estimate.ok, estimate
    return float(np.linalg.norm(estimate.pose()[0] - tip)), estimate.sigma_mm


def test_the_first_try_s_frame_3_is_exact_on_a_flat_fundus() -> None:
    """Not the prediction, the calibration or an acquisition: on a flat fundus the frame's tip is within 0.001 mm and
    3 sigma."""
    error, sigma = _first_try_frame_3("flat")
    assert error < 0.001 and error < 3 * sigma


# Issue 61: two vessels cross this spot (0.5 mm on the retina, 19 px in radius) near its edge and read it 0.6 px inside
# on average (RMS 0.73 px about the true cone, 0.02 px on a flat fundus): the tip is 0.096 mm low. The fit's
# covariance sees the scatter (sigma_mm 0.028 against 0.008 for its neighbours; lag-1 correlation 0.82), and the
# error lies along its major axis (the height, 94-99.9 % of the trace): 4.4 sigma_mm, a per-axis sigma, but 2.5 of
# the 3-D standard error that a 3-D distance is measured against (evaluate's, before issue 61, was the per-axis one).
# A model of the vessels' whole-edge shift is issue 65's.
def test_the_first_try_s_frame_3_is_within_3_sigma_on_the_retina() -> None:
    error, sigma = _first_try_frame_3("retina")
    assert within_sigmas(error, sigma) and not error < 3 * sigma, (error, sigma)
