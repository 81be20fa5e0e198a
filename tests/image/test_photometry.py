"""The photometric edge: the beam's blurred profile in closed form, and clipped spots read from their flank."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav import Renderer
from spotnav.experiments.faults import SILENT_ERROR_MM
from spotnav.experiments.scenes import thesis_world, with_true_edge
from spotnav.image.photometry import edge_light, pixel_light
from spotnav.pose.precise import localize_precise_with_edges
from spotnav.setup.config import EXAMPLE_SETUP, Light, setup_from_toml
from spotnav.setup.paths import path_poses


def _square_below(offset: float, cos: float, sin: float) -> float:
    """The area of the unit pixel square where ``offset + u cos + v sin < 0``, the square clipped by the line
    (Sutherland-Hodgman) and measured by the shoelace formula: exact, for a step the grid below would quantize."""
    corners = [(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)]
    side = [offset + u * cos + v * sin for u, v in corners]
    kept: list[tuple[float, float]] = []
    for i in range(4):
        (u0, v0), (u1, v1), s0, s1 = corners[i], corners[(i + 1) % 4], side[i], side[(i + 1) % 4]
        if s0 < 0.0:
            kept.append((u0, v0))
        if (s0 < 0.0) != (s1 < 0.0):
            t = s0 / (s0 - s1)
            kept.append((u0 + t * (u1 - u0), v0 + t * (v1 - v0)))
    return 0.5 * abs(sum(kept[i - 1][0] * kept[i][1] - kept[i][0] * kept[i - 1][1] for i in range(len(kept))))


def _numerical_light(x: float, band: float, angle: float, blur: float) -> float:
    """The smoothstep band averaged by brute force over a pixel's square (a 200 x 200 grid; a step by the exact
    clipped area) and a box of the blur's variance (128 points)."""
    box = np.sqrt(12.0) * blur * ((np.arange(128) + 0.5) / 128 - 0.5)
    if band == 0.0:
        return float(np.mean([_square_below(x + shift, np.cos(angle), np.sin(angle)) for shift in box]))
    grid = (np.arange(200) + 0.5) / 200 - 0.5
    across, along = np.meshgrid(grid, grid)
    footprint = (across * np.cos(angle) + along * np.sin(angle)).ravel()
    at = x + footprint[:, None] + box[None, :]
    t = np.clip(0.5 - at / band, 0.0, 1.0)
    return float(np.mean(t * t * (3.0 - 2.0 * t)))


@settings(max_examples=60, deadline=None)
@given(
    x=st.floats(-6.0, 6.0),
    band=st.one_of(st.just(0.0), st.floats(0.05, 8.0)),
    angle=st.floats(0.0, 2.0 * np.pi),
    blur=st.one_of(st.just(0.0), st.floats(0.001, 1.0)),
)
def test_pixel_light_is_the_smoothstep_over_the_pixel(x: float, band: float, angle: float, blur: float) -> None:
    # The closed form (differences of the ramp's antiderivatives) against the average by brute force.
    light = pixel_light(x, band, np.cos(angle), np.sin(angle), blur)
    assert light == pytest.approx(_numerical_light(x, band, angle, blur), abs=2e-3)


@settings(max_examples=40, deadline=None)
@given(x=st.floats(-6.0, 6.0), band=st.floats(0.0, 6.0), angle=st.floats(0.0, 2.0 * np.pi), blur=st.floats(0.0, 1.0))
def test_pixel_light_is_symmetric_about_its_half_light_point(x: float, band: float, angle: float, blur: float) -> None:
    # The band's smoothstep and the footprint are both symmetric: the pixel's box leaves the half-light point.
    cos, sin = np.cos(angle), np.sin(angle)
    assert pixel_light(x, band, cos, sin, blur) + pixel_light(-x, band, cos, sin, blur) == pytest.approx(1.0, abs=1e-9)
    assert pixel_light(x, band, cos, sin, blur) >= pixel_light(x + 0.1, band, cos, sin, blur) - 1e-12


def test_edge_light_of_the_example_beam() -> None:
    # The band runs from beta in to 2 edge - beta, the edge the half-light angle of blend 0.15; a point light's
    # apex is the tip.
    setup = setup_from_toml(EXAMPLE_SETUP)
    beta = np.radians(9.0)
    edge = np.arccos(np.cos(beta) + 0.075 * (1.0 - np.cos(beta)))
    light = edge_light(setup, np.array([1.0, 2.0, 5.0]), np.array([0.0, 0.0, -1.0])).light
    np.testing.assert_allclose(light, [1.0, 2.0, 5.0, 0.0, 0.0, -1.0, 2.0 * edge - beta, beta, 12.5], rtol=1e-12)


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
