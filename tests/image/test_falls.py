"""Rays whose fall a structure along the edge shaped, and the runs they lie in."""

from __future__ import annotations

import numpy as np
from conftest import small_setup
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav.image.falls import _long_runs
from spotnav.image.photometry import edge_light
from spotnav.image.rays import detect_edge_subpixel
from spotnav.image.spots import detect_spots_otsu
from spotnav.optics.render import Renderer
from spotnav.optics.response import decoding_table, encoding_table
from spotnav.setup.geometry import InstrumentPose


def _darken(image: np.ndarray, mask: np.ndarray, factor: float) -> np.ndarray:
    """``image`` (sRGB, 8 bits) with its light inside ``mask`` multiplied by ``factor`` (a structure's albedo)."""
    light = decoding_table("srgb", 8)[image]
    light[mask] *= factor
    return encoding_table("srgb", 8)[np.round(light * 65535).astype(int)]


def test_rays_whose_fall_a_vessel_along_the_edge_shaped_are_left_out() -> None:
    # Flat albedo at 1024 px; a vessel 3 px wide, darkening by 40 %, runs along a quarter of the edge on its inner
    # fall: the half level is the plateau's, so the rays under it would cross it half a pixel or more inward. Their
    # falls differ from the spot's: every one of them (but where the vessel ends) is left out, counted as
    # misshapen, no ray off the vessel is, and the edge kept off the vessel's ends lies where the clean frame's
    # does. The clean frame's rays all keep their edge.
    setup = small_setup(1024, blend=0.15, texture="flat", full_well_e=0.0)
    pose = InstrumentPose.through_insertion([1.0, -1.5, 4.5], setup.instrument.insertion_in_eye)
    image = Renderer(setup).render(pose)
    spot = detect_spots_otsu(image).spots[0]
    light = edge_light(setup, pose.tip_in_eye, pose.axis)
    clean = detect_edge_subpixel(image, spot, light=light)
    assert clean.misshapen_rays == 0 and len(clean.pixels) == clean.rays
    centre = clean.pixels.mean(axis=0)
    clean_radii = np.hypot(*(clean.pixels - centre).T)
    radius = clean_radii.mean()
    v, u = np.mgrid[: image.shape[0], : image.shape[1]]
    distance, angle = np.hypot(u - centre[0], v - centre[1]), np.arctan2(v - centre[1], u - centre[0])
    vessel = (np.abs(distance - radius + 1.5) < 1.5) & (angle > 0.0) & (angle < np.pi / 2)
    edge = detect_edge_subpixel(_darken(image, vessel, 0.6), spot, light=light)
    kept = np.isin(clean.ray_angles, edge.ray_angles)
    turn = clean.ray_angles % (2 * np.pi)
    on_arc, near_arc = (turn > 0.05) & (turn < np.pi / 2 - 0.05), (turn < np.pi / 2 + 0.05) | (turn > 2 * np.pi - 0.05)
    assert not kept[on_arc].any() and kept[~near_arc].all()
    assert edge.misshapen_rays >= on_arc.sum()
    off_arc = ~near_arc[kept]  # the rays kept away from the vessel's ends
    np.testing.assert_allclose(np.hypot(*(edge.pixels[off_arc] - centre).T), clean_radii[kept][off_arc], atol=0.05)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(st.booleans(), st.booleans()), min_size=1, max_size=40),
    st.integers(min_value=1, max_value=6),
)
def test_long_runs_are_the_marked_rays_in_runs_around_the_spot(rays: list[tuple[bool, bool]], length: int) -> None:
    # Around the spot (the last ray next to the first), the rays not judged skipped: a marked ray is kept where
    # its run of marked rays is at least ``length`` long.
    marked, judged = np.array([m and j for m, j in rays]), np.array([j for _, j in rays])
    order = np.flatnonzero(judged)
    expected = np.zeros(len(rays), dtype=bool)
    for k, ray in enumerate(order):
        if marked[ray]:
            run = [ray]
            for step in (1, -1):
                j = k + step
                while marked[order[j % len(order)]] and len(run) < len(order):
                    run.append(order[j % len(order)])
                    j += step
            expected[ray] = len(set(run)) >= length
    np.testing.assert_array_equal(_long_runs(marked, judged, length), expected)
