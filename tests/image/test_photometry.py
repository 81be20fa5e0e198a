"""The photometric edge: the beam's blurred profile over a pixel in closed form, and where its band lies."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav.image.photometry import edge_light, pixel_light, ray_light_blurs
from spotnav.optics.camera import project_points, unproject_pixels_to_sphere
from spotnav.optics.defocus import light_blur_px
from spotnav.setup.config import setup_from_toml
from spotnav.setup.examples import EXAMPLE_SETUP


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
    # apex is the tip; no lens (a pinhole): no blur, focused at the pole's depth.
    setup = setup_from_toml(EXAMPLE_SETUP)
    beta = np.radians(9.0)
    edge = np.arccos(np.cos(beta) + 0.075 * (1.0 - np.cos(beta)))
    light = edge_light(setup, np.array([1.0, 2.0, 5.0]), np.array([0.0, 0.0, -1.0])).light
    expected = [1.0, 2.0, 5.0, 0.0, 0.0, -1.0, 2.0 * edge - beta, beta, 12.5, 0.0, 0.0, 1.0 / 110.0]
    np.testing.assert_allclose(light, expected, rtol=1e-12)


def test_each_ray_s_light_blur_is_the_lens_s_at_its_crossing() -> None:
    setup = setup_from_toml(EXAMPLE_SETUP.replace("distance_mm = 110.0", "distance_mm = 110.0\naperture_mm = 20.0"))
    light = edge_light(setup, np.array([3.0, 0.0, 4.0]), np.array([0.0, 0.0, -1.0]))
    centre = project_points(setup.camera, np.array([3.0, 0.0, 12.5 - np.sqrt(12.5**2 - 9.0)]))
    angles, crossings = np.array([0.0, np.pi / 2, np.pi]), np.array([80.0, 80.0, 80.0])
    blurs = ray_light_blurs(light.model, light.light, centre, angles, crossings)
    pixels = centre + crossings[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    points = unproject_pixels_to_sphere(setup.camera, pixels, setup.eye.radius_mm)
    np.testing.assert_allclose(blurs, light_blur_px(setup.camera, points), rtol=1e-9)
    assert blurs[0] > blurs[1] > blurs[2] > 0.0  # outward from the pole: deeper, off the focus further
