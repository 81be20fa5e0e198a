"""The Cramer-Rao bound of a pose: how it scales with the light and the camera, and that an efficient fit reaches it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from spotnav.experiments.scenes import thesis_world
from spotnav.optics.render import Renderer
from spotnav.pose.bound import pose_bound
from spotnav.pose.model_fit import fit_model_to_frame
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose

TIP_MM = np.array([1.0, 0.5, 5.0])


def _world(size_px: int, beams: int = 1, power_w: float = 1.0, **render: float) -> Setup:
    world = thesis_world(size_px, beams, power_w)
    return replace(world, render=replace(world.render, **render))


def _pose(world: Setup, tip: np.ndarray = TIP_MM) -> InstrumentPose:
    return InstrumentPose.through_insertion(tip, world.instrument.insertion_in_eye)


def test_shot_limited_bound_falls_as_one_over_root_power() -> None:
    # Shot noise alone: no read noise, no ambient light, 16 bits (rounding 1/65535), spots far from full scale.
    quiet = {"read_noise_e": 0.0, "ambient": 0.0, "bit_depth": 16, "exposure_stops": -2.0}
    weak = pose_bound(_world(384, power_w=0.1, **quiet), _pose(_world(384)))
    strong = pose_bound(_world(384, power_w=0.4, **quiet), _pose(_world(384)))
    assert weak.ok and strong.ok and weak.clipped_share == 0.0
    # Four times the power, half the bound: exactly, but for the 16-bit rounding (measured 2.0001).
    assert weak.tip_mm / strong.tip_mm == pytest.approx(2.0, rel=1e-3)
    assert weak.tip_sd_mm / strong.tip_sd_mm == pytest.approx(np.full(3, 2.0), rel=1e-3)


def test_quantization_limited_bound_falls_as_one_over_resolution() -> None:
    # No sensor noise: only the 8-bit rounding (1/12 code^2). The soft edge spans some 3.6 px at 1024 px; below a
    # few pixels the pixels average the edge and the law bends (2.14 from 512 to 1024 px).
    coarse = pose_bound(_world(1024, full_well_e=0.0), _pose(_world(1024)))
    fine = pose_bound(_world(2048, full_well_e=0.0), _pose(_world(2048)))
    assert coarse.ok and fine.ok
    assert coarse.tip_mm / fine.tip_mm == pytest.approx(2.0, rel=0.10)


def test_the_clip_takes_information_and_the_bound_grows() -> None:
    world = _world(384)
    bright = replace(world, render=replace(world.render, exposure_stops=3.0))
    plain, clipped = pose_bound(world, _pose(world)), pose_bound(bright, _pose(world))
    assert plain.clipped_share < 0.01 < 0.2 < clipped.clipped_share
    # Three stops more light would shrink a shot-limited bound by 2^1.5 = 2.8; the clip keeps it from doing so.
    assert clipped.tip_mm > plain.tip_mm / 2.0**1.5


def test_an_axis_the_localizer_must_fit_too_loosens_the_tip() -> None:
    world = _world(384, beams=3)
    pose = _pose(world)
    known, free = pose_bound(world, pose), pose_bound(world, pose, through_insertion=False)
    assert known.parameters == ("tip_x_mm", "tip_y_mm", "tip_z_mm", "roll", "log_power")
    assert free.parameters == ("tip_x_mm", "tip_y_mm", "tip_z_mm", "tilt_e1", "tilt_e2", "roll", "log_power")
    assert np.all(free.tip_sd_mm >= known.tip_sd_mm)
    assert free.axis_deg > known.axis_deg > 0.0


def test_light_that_misses_the_retina_has_no_bound() -> None:
    world = _world(256)
    away = InstrumentPose(TIP_MM, np.array([0.0, 0.0, 1.0]))  # toward the cornea
    bound = pose_bound(world, away, through_insertion=False)
    assert bound.status == "no_light" and not bound.ok and np.isnan(bound.tip_mm)


@pytest.mark.parametrize("beams", [1, pytest.param(3, marks=pytest.mark.slow)])  # three beams: 35 s, make test-all
def test_an_efficient_fit_of_200_noisy_frames_spreads_as_the_bound(beams: int) -> None:
    """The bound is the spread of the model fit's estimates over 200 noisy renders of one pose, within 20 %."""
    world = _world(384, beams=beams)
    pose = _pose(world)
    bound = pose_bound(world, pose)
    renderer = Renderer(world)
    tips = []
    for seed in range(200):  # the local maximum-likelihood estimate: from the true pose, one round
        fit = fit_model_to_frame(renderer.render(pose, seed=seed), world, pose, rounds=1)
        assert fit.ok and fit.pose is not None
        tips.append(fit.pose.tip_in_eye)
    spread = np.std(tips, axis=0, ddof=1)
    # The sample's sigma has a relative standard error of 1/sqrt(2 * 199) = 5 %: 20 % is four of them.
    assert spread == pytest.approx(bound.tip_sd_mm, rel=0.20)
    bias = np.mean(tips, axis=0) - TIP_MM
    assert np.all(np.abs(bias) < 4.0 * bound.tip_sd_mm / np.sqrt(200))  # unbiased within 4 standard errors


def test_a_hard_edge_a_tip_outside_the_eye_and_no_power_have_no_bound() -> None:
    world = _world(256)
    hard = replace(world, light=replace(world.light, blend=0.0))
    assert pose_bound(hard, _pose(world)).status == "hard_edge"
    assert pose_bound(world, _pose(world, np.array([0.0, 0.0, 30.0]))).status == "outside_eye"
    dark = replace(world, light=replace(world.light, power_w=0.0))
    assert pose_bound(dark, _pose(world)).status == "no_light"
