"""The model fit: from the precise method's pose to the bound, and its residuals when the model is not the world."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from spotnav.experiments.scenes import thesis_world, with_true_edge
from spotnav.optics.render import Renderer
from spotnav.pose.bound import pose_bound
from spotnav.pose.model_fit import fit_model_to_frame
from spotnav.pose.precise import localize_precise
from spotnav.setup.geometry import InstrumentPose

TIP_MM = np.array([-0.8, 1.2, 5.5])


@pytest.mark.parametrize("beams", [1, 3])
def test_the_fit_from_the_precise_pose_lands_within_the_bound(beams: int) -> None:
    world = thesis_world(512, beams, 1.0)
    pose = InstrumentPose.through_insertion(TIP_MM, world.instrument.insertion_in_eye)
    image = Renderer(world).render(pose, seed=3)
    precise = localize_precise(image, with_true_edge(world))
    assert precise.ok and precise.tip_in_eye is not None and precise.axis is not None
    fit = fit_model_to_frame(image, world, InstrumentPose(precise.tip_in_eye, precise.axis))
    assert fit.ok and fit.pose is not None
    bound = pose_bound(world, pose)
    error = fit.pose.tip_in_eye - TIP_MM
    assert np.all(np.abs(error) < 4.0 * bound.tip_sd_mm)  # one frame: within 4 sigmas of the bound per axis
    assert np.linalg.norm(error) < np.linalg.norm(precise.tip_in_eye - TIP_MM)  # and nearer than precise's
    assert 0.6 < fit.chi2_per_pixel < 1.3  # the model is the world: the residuals are the noise
    assert np.sqrt(np.diag(fit.covariance)[:3]) == pytest.approx(bound.tip_sd_mm, rel=0.05)


def test_its_residuals_say_when_the_light_is_not_the_setups() -> None:
    world = thesis_world(512, 1, 1.0)
    pose = InstrumentPose.through_insertion(TIP_MM, world.instrument.insertion_in_eye)
    image = Renderer(world).render(pose, seed=3)
    wrong = replace(world, light=replace(world.light, blend=0.3))  # a softer edge than the frame's
    right_fit, wrong_fit = fit_model_to_frame(image, world, pose), fit_model_to_frame(image, wrong, pose)
    assert right_fit.ok and 0.6 < right_fit.chi2_per_pixel < 1.3
    # The wrong edge fits nowhere: the fit does not settle, or settles on residuals far above the noise.
    assert wrong_fit.chi2_per_pixel > 2.0 * right_fit.chi2_per_pixel


def test_light_that_misses_the_retina_is_no_fit() -> None:
    world = thesis_world(256, 1, 1.0)
    image = Renderer(world).render(InstrumentPose.through_insertion(TIP_MM, world.instrument.insertion_in_eye))
    away = InstrumentPose(TIP_MM, np.array([0.0, 0.0, 1.0]))
    fit = fit_model_to_frame(image, world, away, through_insertion=False)
    assert fit.status == "no_light" and not fit.ok and fit.pose is None


def test_a_start_too_far_is_said_not_answered() -> None:
    world = thesis_world(384, 3, 1.0)
    pose = InstrumentPose.through_insertion(TIP_MM, world.instrument.insertion_in_eye)
    image = Renderer(world).render(pose, seed=3)
    far = InstrumentPose.through_insertion(TIP_MM + 0.3, world.instrument.insertion_in_eye)
    fit = fit_model_to_frame(image, world, far)
    assert fit.status == "unconverged" and fit.pose is None and fit.chi2_per_pixel > 10.0


def test_a_frame_blurred_after_its_encoding_is_a_mismatch_not_an_answer() -> None:
    world = thesis_world(512, 1, 1.0)
    pose = InstrumentPose.through_insertion(TIP_MM, world.instrument.insertion_in_eye)
    blurred = replace(world, faults=replace(world.faults, frame_blur_px=1.5))
    fit = fit_model_to_frame(Renderer(blurred).render(pose, seed=3), world, pose)
    assert fit.status == "mismatch" and fit.pose is None and fit.chi2_per_pixel > 2.0
