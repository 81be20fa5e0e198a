"""Clipped spots read from their flank: answered within their sigma, or refused."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from spotnav import Renderer
from spotnav.app.paths import path_poses
from spotnav.experiments.chapter6 import thesis_world, with_true_edge
from spotnav.experiments.faults import SILENT_ERROR_MM
from spotnav.experiments.scenes import with_lens_blur
from spotnav.pose.precise import localize_precise_with_edges
from spotnav.setup.config import Light


@pytest.mark.parametrize(("stops", "blend", "tolerance_mm"), [(4.5, 0.15, 0.03), (6.0, 0.15, 0.05)])
def test_a_clipped_spot_is_read_from_its_flank(stops: float, blend: float, tolerance_mm: float) -> None:
    # The thesis's exposure (+4.5 stops: every channel at full scale inside the spot) and beyond: answered, not
    # refused, within the tolerance and within 3 sigma (sigma_mm is per axis).
    world = thesis_world(1024, 1, 1.0, exposure_stops=stops)
    world = replace(world, light=Light(power_w=1.0, blend=blend))
    setup = with_true_edge(world)
    renderer = Renderer(world)
    for i, pose in enumerate(path_poses("helix", 8, world.instrument.insertion_in_eye)[::3]):
        result = localize_precise_with_edges(renderer.render(pose, seed=i), setup)
        estimate = result.estimate
        assert estimate.ok, estimate.detail
        error = float(np.linalg.norm(estimate.tip_in_eye - pose.tip_in_eye))
        assert error < tolerance_mm
        assert error < 3.0 * np.sqrt(3.0) * estimate.sigma_mm


@pytest.mark.parametrize("step", [7, 8])
def test_a_spot_that_barely_clips_is_answered_within_its_sigma(step: int) -> None:
    # +3 stops at 2048 px: the plateau just over full scale on most rays, the amplitude at the search grid's lower
    # end. Once refused (the flank's model error taken as large as where most of it is clipped: 0.037 mm).
    world = thesis_world(2048, 1, 1.0, exposure_stops=3.0)
    pose = path_poses("helix", 10, world.instrument.insertion_in_eye)[step]
    estimate = localize_precise_with_edges(Renderer(world).render(pose, seed=step), with_true_edge(world)).estimate
    assert estimate.ok, estimate.detail
    error = float(np.linalg.norm(estimate.tip_in_eye - pose.tip_in_eye))
    assert error < 3.0 * np.sqrt(3.0) * estimate.sigma_mm
    assert error < 0.03


def test_the_amplitude_search_does_not_settle_on_a_far_brighter_light() -> None:
    # A spot at 0.5 W, thesis's exposure, whose flank's cost on a few rays is as low 60 times too bright: the
    # search once chose that and put the tip 0.043 mm off at a sigma of 0.004 mm.
    world = thesis_world(1024, 1, 0.5, exposure_stops=4.5)
    pose = path_poses("helix", 25, world.instrument.insertion_in_eye)[0]
    result = localize_precise_with_edges(Renderer(world).render(pose, seed=0), with_true_edge(world))
    estimate = result.estimate
    assert estimate.ok, estimate.detail
    error = float(np.linalg.norm(estimate.tip_in_eye - pose.tip_in_eye))
    assert error < 3.0 * np.sqrt(3.0) * estimate.sigma_mm
    assert error < 0.01


def test_a_sharp_beam_blown_out_to_a_step_is_refused() -> None:
    # No soft band: beyond the pixels' own footprint no flank is left whose shape pins the edge.
    world = replace(thesis_world(1024, 1, 1.0, exposure_stops=6.0), light=Light(power_w=1.0, blend=0.0))
    pose = path_poses("helix", 8, world.instrument.insertion_in_eye)[0]
    estimate = localize_precise_with_edges(Renderer(world).render(pose, seed=0), with_true_edge(world)).estimate
    assert estimate.status == "unreliable"
    assert "full scale in every channel" in estimate.detail


@pytest.mark.parametrize(
    ("blur_px", "tolerance_mm", "frames", "answered"), [(1.0, 0.03, 3, 1), (2.0, SILENT_ERROR_MM, 2, 0)]
)
def test_a_clipped_spot_in_a_frame_blurred_after_its_encoding_is_read_with_that_blur(
    blur_px: float, tolerance_mm: float, frames: int, answered: int
) -> None:
    # The noise beside the spot tells the frame's blur (the clipped spot's least bright channel, which the edge is
    # read in, has a background too dark for it: the brighter channels' noise tells it), and the flank is read
    # again with it in its model. Without it the flank's edge moved by some 0.3 px at 1 px (tips 0.04-0.07 mm
    # off) and such frames were refused `blurred`. The blur's uncertainty moves the edges (a wider blur takes a
    # brighter light): a frame is answered within 3 sigma, or refused for its tip's uncertainty.
    world = thesis_world(1024, 1, 1.0, exposure_stops=4.5)
    setup = with_true_edge(world)
    ok = 0
    for i, pose in enumerate(path_poses("helix", 16, world.instrument.insertion_in_eye)[:frames]):
        frame = cv2.GaussianBlur(Renderer(world).render(pose, seed=i), (0, 0), blur_px)
        estimate = localize_precise_with_edges(frame, setup).estimate
        if not estimate.ok:
            assert estimate.status == "unreliable", estimate
            assert "tip uncertainty" in estimate.detail
            continue
        ok += 1
        error = float(np.linalg.norm(estimate.tip_in_eye - pose.tip_in_eye))
        assert error < 3.0 * np.sqrt(3.0) * estimate.sigma_mm
        assert error < tolerance_mm
    assert ok >= answered


@pytest.mark.xfail(
    strict=True,
    reason="known gap: at 768 px one stated-lens tip lies 0.055 mm off (the model's blur is a box of the blur's "
    "variance, the renderer's a Gaussian: their tails differ on a clipped flank)",
)
def test_a_clipped_spot_through_a_lens_is_read_with_the_lens_s_blur_when_the_setup_states_it() -> None:
    # +4.5 stops through a lens focused at the pole whose depth of field blurs the helix's spots by 1 px (their
    # median, up to 2.6 px): a blur of the light that the flank's model leaves out reads as a dimmer light, the edge
    # further out. Stated, each answer lies within its sigma (a spot blurred the most may be refused unreliable:
    # its flank pins the amplitude less); unstated, the tips lie further off. Measured at 1024 px, 8 helix tips:
    # stated 7 answered, 0.013 / 0.027 mm, all within 3 sigma; unstated 0.105 / 0.257 mm.
    world = with_lens_blur(thesis_world(768, 1, 1.0, exposure_stops=4.5), 1.0)
    stated = with_true_edge(world)
    unstated = replace(stated, camera=replace(stated.camera, aperture_mm=None))
    renderer = Renderer(world)
    errors: dict[str, list[float]] = {"stated": [], "unstated": []}
    for i, pose in enumerate(path_poses("helix", 16, world.instrument.insertion_in_eye)[1::4]):
        frame = renderer.render(pose, seed=i)
        for name, setup in (("stated", stated), ("unstated", unstated)):
            estimate = localize_precise_with_edges(frame, setup).estimate
            if not estimate.ok:
                assert name == "unstated" or estimate.status == "unreliable", estimate
                continue
            error = float(np.linalg.norm(estimate.tip_in_eye - pose.tip_in_eye))
            errors[name].append(error)
            if name == "stated":
                assert error < 0.03
                assert error < 3.0 * np.sqrt(3.0) * estimate.sigma_mm
    assert len(errors["stated"]) >= 3 and len(errors["unstated"]) >= 3, errors
    assert np.mean(errors["unstated"]) > 2.0 * np.mean(errors["stated"]), errors
