"""Fragments of a spot grouped into one, and a spot's outer boundary."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from image_frames import disc_image, fragments_of

from spotnav.image.fragments import _near_hull
from spotnav.image.spots import detect_spots_otsu


@settings(max_examples=30)
@given(seed=st.integers(0, 2**31), count=st.integers(5, 300), tolerance=st.floats(0.1, 10.0))
def test_points_near_the_hull_are_those_near_a_side_s_line(seed: int, count: int, tolerance: float) -> None:
    points = np.random.default_rng(seed).normal(size=(count, 2)) * 30.0
    hull = cv2.convexHull(points.astype(np.float32)).reshape(-1, 2).astype(float)
    near = _near_hull(points, tolerance)
    for point, is_near in zip(points, near, strict=True):
        sides = np.roll(hull, -1, axis=0) - hull
        offsets = point - hull
        distances = np.abs(sides[:, 0] * offsets[:, 1] - sides[:, 1] * offsets[:, 0]) / np.hypot(*sides.T)
        assert is_near == (len(hull) < 3 or distances.min() <= tolerance)
    assert near[np.argmin(points[:, 0])]  # the leftmost point is a corner of the hull


def test_a_spot_cut_by_vessels_is_one_spot() -> None:
    # Three dark lines across one disc leave six fragments; their outer boundaries lie on one circle.
    image = disc_image([(200, 200)], radius=60)
    for angle in (0.3, 1.4, 2.5):
        direction = 90 * np.array([np.cos(angle), np.sin(angle)])
        cv2.line(image, tuple((200 - direction).astype(int)), tuple((200 + direction).astype(int)), (15,) * 3, 6)
    assert len(detect_spots_otsu(image, min_area_fraction=0.005).spots) == 6
    grouped = fragments_of(image)
    assert len(grouped.spots) == 1 and grouped.fragments == 6 and grouped.regions == "6 bright regions in 1 spot"
    distances = np.hypot(*(grouped.spots[0].contour_px - 200).T)  # whole pixels of a blurred, thresholded disc
    assert np.abs(distances.mean() - 60) < 1.0 and np.abs(distances - 60).max() < 3.0
    assert grouped.spots[0].area_px == pytest.approx(np.pi * 60**2, rel=0.05)


def test_separate_spots_and_a_glint_beside_a_spot_stay_apart() -> None:
    # Two whole discs 10 px apart (closer than the gap) are two spots; a glint 10 px beside one (within the
    # gap too) is not part of it: the disc's outline stays the circle's.
    image = disc_image([(140, 200), (240, 200)], radius=45)
    cv2.circle(image, (140, 140), 5, (255, 255, 255), -1)
    grouped = fragments_of(image, whole_area_px=1000.0)
    assert [round(s.area_px / (np.pi * 45**2), 1) for s in grouped.spots[:2]] == [1.0, 1.0]
    for spot in grouped.spots[:2]:
        centre = (140, 200) if spot.contour_px[:, 0].mean() < 190 else (240, 200)
        assert np.hypot(*(spot.contour_px - centre).T).max() < 47
    assert len(grouped.spots) == 2  # the glint is clutter beside them
