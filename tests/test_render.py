from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import small_setup

from spotnav.camera import project_points
from spotnav.config import Bump, World
from spotnav.geometry import InstrumentPose, cone_sphere_curve
from spotnav.render import Renderer, bump_height, exposure_gain


def test_full_scale_at_5_mm_for_1_w() -> None:
    # White, facing, 5 mm, 1 W: irradiance 1 / (100 pi) W/mm^2 -> exactly 1.0.
    assert exposure_gain(0.0) / (100.0 * np.pi) == pytest.approx(1.0)
    setup = small_setup(256, full_well_e=0.0, texture="flat", ambient=0.0)
    image = Renderer(setup).render(InstrumentPose([0.0, 0.0, 5.0], [0.0, 0.0, -1.0]))
    center = image[127:129, 127:129, 0].astype(float).mean()
    albedo_red = 0.78
    expected = 255 * (1.055 * albedo_red ** (1 / 2.4) - 0.055)
    assert center == pytest.approx(expected, abs=1.5)


def test_frames_are_seeded(renderer_512: Renderer) -> None:
    pose = InstrumentPose.through_insertion([1.0, -1.0, 4.0], renderer_512.setup.instrument.insertion_in_eye)
    first = renderer_512.render(pose, seed=3)
    assert first.shape == (512, 512, 3) and first.dtype == np.uint8
    np.testing.assert_array_equal(first, renderer_512.render(pose, seed=3))
    assert not np.array_equal(first, renderer_512.render(pose, seed=4))


def test_spot_lies_inside_the_projected_cone_curve(renderer_512: Renderer) -> None:
    setup = renderer_512.setup
    pose = InstrumentPose.through_insertion([-1.5, 0.5, 4.5], setup.instrument.insertion_in_eye)
    image = renderer_512.render(pose, seed=0).astype(float)
    curve = cone_sphere_curve(
        pose.tip_in_eye, pose.axis, setup.instrument.beam_half_angle, setup.eye.center_in_eye, 12.5
    )
    pixels = project_points(setup.camera, curve)
    lit = image[..., 0] > 100
    v, u = np.nonzero(lit)
    assert lit.sum() > 100
    # The lit region's bounding box matches the curve's to within a pixel or two.
    assert u.min() == pytest.approx(pixels[:, 0].min(), abs=2.0)
    assert u.max() == pytest.approx(pixels[:, 0].max(), abs=2.0)
    assert v.min() == pytest.approx(pixels[:, 1].min(), abs=2.0)
    assert v.max() == pytest.approx(pixels[:, 1].max(), abs=2.0)


def test_no_power_no_spot(renderer_512: Renderer) -> None:
    pose = InstrumentPose([0.0, 0.0, 5.0], [0.0, 0.0, -1.0])
    dark = renderer_512.render(pose, power_w=0.0)
    assert dark.max() < 60


def test_three_beams_make_three_spots() -> None:
    from scipy import ndimage

    setup = small_setup(512)
    setup = replace(setup, instrument=replace(setup.instrument, beam_count=3))
    image = Renderer(setup).render(InstrumentPose([0.0, 0.0, 4.0], [0.0, 0.0, -1.0]))
    _, count = ndimage.label(image[..., 0] > 100)
    assert count == 3


def test_bumps_displace_the_surface() -> None:
    bump = Bump(0.0, 0.0, radius_mm=0.25, height_mm=0.1)
    setup = replace(small_setup(512), world=World(bumps=(bump,)))
    renderer = Renderer(setup)
    u, v = np.meshgrid(np.linspace(245, 266, 8), np.linspace(245, 266, 8))
    points, normals = renderer.surface_points(u, v, setup.world.bumps)
    height, _, _ = bump_height(setup.world.bumps, points[..., 0], points[..., 1])
    radial = np.linalg.norm(points - setup.eye.center_in_eye, axis=-1)
    np.testing.assert_allclose(radial + height, 12.5, atol=1e-9)
    assert height.max() > 0.09
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0)
    # A bump under the spot's edge changes the picture.
    pose = InstrumentPose([0.7, 0.0, 4.0], [0.0, 0.0, -1.0])
    plain = Renderer(small_setup(512)).render(pose, seed=0)
    assert np.abs(renderer.render(pose, seed=0).astype(int) - plain).max() > 50


def test_plane_spot_matches_table_6_1() -> None:
    # Section 6.2.2: a beam at (3, 3, 5) straight down on the plane z = 0 draws a circle of
    # diameter 2 * 5 * tan(9 deg) mm centred near pixel (3636.8, 1363.2) at 5000 px; here at 1000 px.
    setup = replace(small_setup(1000), world=World(surface="plane"))
    image = Renderer(setup).render(InstrumentPose([3.0, 3.0, 5.0], [0.0, 0.0, -1.0]))
    lit = image[..., 0] > 128
    rows, cols = np.nonzero(lit)
    scale = 1000 / 5000
    assert cols.mean() == pytest.approx((3636.825 - 2499.5) * scale + 499.5, abs=0.3)
    assert rows.mean() == pytest.approx((1363.171 - 2499.5) * scale + 499.5, abs=0.3)
    diameter_px = 2 * np.sqrt(lit.sum() / np.pi)
    assert diameter_px == pytest.approx(2 * 5 * np.tan(np.radians(9)) * 378.79 * scale, rel=0.01)


def test_noise_is_seeded_white_and_scaled() -> None:
    # Bank-drawn noise: the same seed gives the same frame, another seed other noise with the same spread.
    setup = small_setup(256, texture="flat", ambient=0.2)
    renderer = Renderer(setup)
    pose = InstrumentPose([0.0, 0.0, 4.0], [0.0, 0.0, 1.0])  # pointing away: ambient light only
    a, b = renderer.render(pose, seed=1), renderer.render(pose, seed=2)
    np.testing.assert_array_equal(a, renderer.render(pose, seed=1))
    difference = a[..., 1].astype(float) - b[..., 1]
    assert np.mean(difference != 0) > 0.5
    right = np.corrcoef(difference[:, 1:].ravel(), difference[:, :-1].ravel())[0, 1]
    assert abs(right) < 0.05  # white: neighbours uncorrelated
