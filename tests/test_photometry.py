"""The photometric edge: the beam's blurred profile in closed form, and clipped spots read from their flank."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav import Renderer
from spotnav.config import EXAMPLE_SETUP, Light, setup_from_toml
from spotnav.experiments.chapter6 import path_poses, thesis_world, with_true_edge
from spotnav.photometry import edge_light, profile_light
from spotnav.precise import localize_precise_with_edges


def _numerical_profile(x: float, band: float, blur: float) -> float:
    """The smoothstep band convolved with the Gaussian by quadrature (a fine grid to 10 sigma)."""
    z = np.linspace(-10.0, 10.0, 40001)
    t = np.clip(0.5 - (x + blur * z) / band, 0.0, 1.0)
    weights = np.exp(-0.5 * z * z)
    return float(np.sum(t * t * (3.0 - 2.0 * t) * weights) / np.sum(weights))


@settings(max_examples=60, deadline=None)
@given(
    x=st.floats(-8.0, 8.0),
    band=st.floats(0.2, 6.0),
    blur=st.floats(0.1, 3.0),
)
def test_profile_is_the_smoothstep_convolved_with_the_gaussian(x: float, band: float, blur: float) -> None:
    assert profile_light(x, band, blur) == pytest.approx(_numerical_profile(x, band, blur), abs=2e-6)


@settings(max_examples=40, deadline=None)
@given(x=st.floats(-6.0, 6.0), band=st.floats(0.0, 6.0), blur=st.floats(0.05, 3.0))
def test_profile_is_symmetric_about_its_half_light_point(x: float, band: float, blur: float) -> None:
    # The band's smoothstep and the Gaussian are both symmetric: a blur in light leaves the half-light point.
    assert profile_light(x, band, blur) + profile_light(-x, band, blur) == pytest.approx(1.0, abs=1e-9)
    assert profile_light(x, band, blur) >= profile_light(x + 0.1, band, blur) - 1e-12


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


def test_a_sharp_beam_blown_out_to_a_step_is_refused() -> None:
    # No soft band: beyond the pixels' own footprint no flank is left whose shape pins the edge.
    world = replace(thesis_world(1024, 1, 1.0, exposure_stops=6.0), light=Light(power_w=1.0, blend=0.0))
    pose = path_poses("helix", 8, world.instrument.insertion_in_eye)[0]
    estimate = localize_precise_with_edges(Renderer(world).render(pose, seed=0), with_true_edge(world)).estimate
    assert estimate.status == "unreliable"
    assert "full scale in every channel" in estimate.detail
