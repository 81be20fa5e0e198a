"""The photometric model: the same light as the renderer's frames, and what each pixel tells of it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from spotnav.experiments.scenes import thesis_world
from spotnav.optics.frame_model import FrameModel, code_information, expected_codes
from spotnav.optics.render import Renderer
from spotnav.optics.response import decoding_table
from spotnav.setup.geometry import InstrumentPose, beam_axes


def _pose(world):  # type: ignore[no-untyped-def]
    return InstrumentPose.through_insertion(np.array([1.0, 0.5, 5.0]), world.instrument.insertion_in_eye)


@pytest.mark.parametrize("beams", [1, 3])
def test_the_model_is_the_renderers_noiseless_frame(beams: int) -> None:
    world = thesis_world(384, beams, 1.0)
    world = replace(world, render=replace(world.render, full_well_e=0.0, bit_depth=16))
    pose = _pose(world)
    frame = Renderer(world).render(pose)
    model = FrameModel(world, pose)
    assert model.box is not None
    u0, v0, u1, v1 = model.box
    axes = beam_axes(pose.axis, beams, world.instrument.beam_tilt)
    linear = model.background + model.light(pose.tip_in_eye, axes, world.light.power_w)
    seen = decoding_table(world.camera.pixel_response, 16)[frame[v0:v1, u0:u1]]
    lit = linear > 0.05
    assert lit.sum() > 300
    # The renderer rounds the light to 1/65535 (half a step: 7.6e-6) before encoding it in 16 bits, and reads the
    # light of its own box's pixels: the same light within a few such steps.
    assert np.max(np.abs(seen - np.minimum(linear, 1.0))) < 5e-5
    # The codes the model expects are the frame's, within the rounding.
    codes = expected_codes(world, linear)
    assert np.median(np.abs(codes - frame[v0:v1, u0:u1])[lit]) <= 1.0


def test_a_pixel_weighs_by_its_noise_and_loses_its_information_to_the_clip() -> None:
    world = thesis_world(256, 1, 1.0)
    world = replace(world, render=replace(world.render, bit_depth=16))
    linear = np.array([0.25, 0.5, 0.99, 1.2])
    pixel = code_information(world, linear)
    full_well, read = world.render.full_well_e, world.render.read_noise_e
    variance = linear / full_well + (read / full_well) ** 2
    slope = 65535.0 * 1.055 / 2.4 * linear[:3] ** (1 / 2.4 - 1)  # sRGB's
    assert pixel.slope[:3] == pytest.approx(slope, rel=1e-3)
    assert pixel.noise_weight[:3] == pytest.approx(1.0 / (slope**2 * variance[:3] + 1.0 / 12.0), rel=2e-3)
    assert pixel.unclipped[:2] == pytest.approx([1.0, 1.0])
    assert 0.5 < pixel.unclipped[2] < 1.0  # within a sigma (0.01) of full scale: partly clipped
    assert pixel.weight[3] < 1e-12 * pixel.weight[0]  # 20 sigmas over full scale: nothing left


def test_no_light_no_box() -> None:
    world = thesis_world(256, 1, 1.0)
    away = InstrumentPose(np.array([0.0, 0.0, 5.0]), np.array([0.0, 0.0, 1.0]))  # toward the cornea
    assert FrameModel(world, away).box is None
