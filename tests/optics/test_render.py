from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import small_setup

from spotnav.optics.camera import project_points
from spotnav.optics.occlusion import pixels_behind_segment
from spotnav.optics.render import Renderer, bump_height, exposure_gain
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose, cone_sphere_curve
from spotnav.setup.sections import Bump, World


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


STEEP = InstrumentPose.through_insertion([0.5, 0.5, 4.0], np.array([0.0, 1.0, 24.0]))  # the shaft crosses the spot


def _with_faults(setup: Setup, **faults: object) -> Renderer:
    return Renderer(replace(setup, faults=replace(setup.faults, **faults)))


def test_faults_are_off_by_default_and_change_only_what_they_name(renderer_512: Renderer) -> None:
    setup = renderer_512.setup
    plain = renderer_512.render(STEEP, seed=5).astype(int)
    steel = _with_faults(setup, shaft=True).render(STEEP, seed=5).astype(int)
    u, v = np.meshgrid(np.arange(512.0), np.arange(512.0))
    hidden = pixels_behind_segment(setup.camera, np.stack([u, v], axis=-1), STEEP.tip_in_eye, [0.0, 6.0, 20.0], 0.3)
    assert 200 < hidden.sum() < 20000
    np.testing.assert_array_equal(steel[~hidden], plain[~hidden])  # the same noise elsewhere
    assert np.sum(plain[hidden][:, 0] > 150) > 100  # the shaft crosses the spot ...
    assert np.all(steel[hidden].mean(axis=-1) < 60)  # ... and hides it: dark steel only
    glints = _with_faults(setup, glints=10).render(STEEP, seed=5)
    assert np.sum(glints == 255) > np.sum(plain == 255) + 10
    assert not np.array_equal(glints, _with_faults(setup, glints=10).render(STEEP, seed=6))  # placed by the seed


def test_vessels_blur_and_a_second_source_change_the_spot_as_named(renderer_512: Renderer) -> None:
    setup = renderer_512.setup
    spot = lambda image: image[..., 0].astype(float) > 60  # noqa: E731
    plain = renderer_512.render(STEEP, seed=2)
    vessels = _with_faults(setup, vessels=6, vessel_contrast=1.0).render(STEEP, seed=2)
    assert vessels[spot(plain)].mean() < 0.9 * plain[spot(plain)].mean()
    blurred = _with_faults(setup, motion_blur_px=20.0).render(STEEP, seed=2)
    assert spot(blurred).sum() > 1.1 * spot(plain).sum()  # smeared wider
    assert abs(blurred.astype(float).sum() - plain.astype(float).sum()) < 0.05 * plain.astype(float).sum()
    second = _with_faults(setup, stray_light=2.0).render(STEEP, seed=2)
    far = ~spot(plain) & (second[..., 1] > 200)
    assert far.sum() > 100  # a bright region away from the spot


def test_a_spot_that_grazes_the_border_renders() -> None:
    # Its lit box is one pixel wide once clipped to the image (this pose once raised in np.gradient).
    setup = small_setup(1024)
    pose = InstrumentPose.through_insertion([6.0, 0.0, 4.5], setup.instrument.insertion_in_eye)
    image = Renderer(setup).render(pose, seed=0)
    assert image.shape == (1024, 1024, 3) and image.dtype == np.uint8


@pytest.mark.parametrize("tip", [(0.0, 0.0, 40.0), (13.0, 0.0, 12.5), (0.0, 0.0, -0.1)])
def test_a_tip_outside_the_eye_is_a_clear_error(tip: tuple[float, float, float]) -> None:
    with pytest.raises(ValueError, match=r"lies outside the eye \(radius 12.5 mm") as error:
        Renderer(small_setup(64)).render(InstrumentPose(list(tip), [0.0, 0.0, -1.0]))
    assert "\n" not in str(error.value)


def _faulted(**faults: object) -> tuple[np.ndarray, np.ndarray]:
    """A 512 px frame without and with ``faults`` (same pose and seed)."""
    world = small_setup(512)
    pose = InstrumentPose.through_insertion([0.0, 0.5, 4.5], world.instrument.insertion_in_eye)
    disturbed = replace(world, faults=replace(world.faults, **faults))
    return Renderer(world).render(pose, seed=3), Renderer(disturbed).render(pose, seed=3)


def test_a_glow_brightens_a_broad_part_of_the_frame() -> None:
    # 5 % of full scale over a third of the frame: many pixels brighter, none darker beyond the noise.
    plain, glowing = _faulted(glow=0.05)
    gain = glowing.astype(float).mean(axis=2) - plain.astype(float).mean(axis=2)
    assert np.mean(gain > 10) > 0.05 and np.mean(gain < -3) < 0.01


def test_a_dark_patch_darkens_part_of_the_spot_s_edge_only() -> None:
    plain, patched = _faulted(dark_patch=0.5)
    loss = plain.astype(float).mean(axis=2) - patched.astype(float).mean(axis=2)
    assert 50 < np.count_nonzero(loss > 20) < 0.5 * np.count_nonzero(plain.mean(axis=2) > 60)


@pytest.mark.parametrize("kind", ["defocus_px", "frame_blur_px"])
def test_blur_in_light_or_after_encoding_softens_the_edge(kind: str) -> None:
    plain, blurred = _faulted(**{kind: 3.0})
    steepest = [np.abs(np.diff(f.astype(float).mean(axis=2), axis=1)).max() for f in (plain, blurred)]
    assert steepest[1] < 0.6 * steepest[0]


def test_a_lens_blurs_the_light_the_more_the_further_its_retina_lies_from_the_focus() -> None:
    # Focused at the pole: a spot near the pole stays sharp (0.46 px at its centre), one 3 mm out (0.37 mm deeper,
    # 3.2 px) is blurred.
    world = small_setup(512)
    lens = replace(world, camera=replace(world.camera, aperture_mm=60.0))
    steepest = {}
    for name, tip in (("pole", [0.0, 0.0, 4.0]), ("out", [3.0, 0.0, 4.0])):
        pose = InstrumentPose.through_insertion(tip, world.instrument.insertion_in_eye)
        frames = [Renderer(w).render(pose, seed=3).astype(float).mean(axis=2) for w in (world, lens)]
        steepest[name] = [np.abs(np.diff(f, axis=1)).max() for f in frames]
    kept = {name: after / before for name, (before, after) in steepest.items()}
    assert kept["out"] < 0.5 < kept["pole"] < 1.0, kept
