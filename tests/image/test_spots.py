"""Spot detection as the thesis does it: Otsu's threshold on the grey frame (shrunk or refined), its histograms."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from conftest import small_setup
from hypothesis import given, settings
from hypothesis import strategies as st
from image_frames import disc_image

from spotnav.image.channels import (
    to_gray8,
)
from spotnav.image.spots import _background_level, _histograms, _opening, detect_spots_otsu, otsu_threshold
from spotnav.optics.render import Renderer
from spotnav.setup.geometry import InstrumentPose


def test_one_disc_gives_one_round_contour() -> None:
    detection = detect_spots_otsu(disc_image([(200, 180)]))
    assert len(detection.spots) == 1
    spot = detection.spots[0]
    assert not spot.touches_border
    distances = np.hypot(spot.contour_px[:, 0] - 200, spot.contour_px[:, 1] - 180)
    assert distances.mean() == pytest.approx(40, abs=1.0)
    assert detection.contrast > 100


@pytest.mark.parametrize("decimate", [1, 4])
@pytest.mark.parametrize("center", [(20, 200), (280, 200), (150, 20), (150, 380), (30, 30)])
def test_a_spot_on_any_edge_of_the_frame_touches_its_border(decimate: int, center: tuple[int, int]) -> None:
    def frame(center: tuple[int, int]) -> np.ndarray:  # 300 px wide, 400 high
        return np.ascontiguousarray(disc_image([center])[:, :300])

    assert detect_spots_otsu(frame(center), decimate=decimate).spots[0].touches_border
    inside = (center[0] + (150 - center[0]) // 2, center[1] + (200 - center[1]) // 2)
    assert not detect_spots_otsu(frame(inside), decimate=decimate).spots[0].touches_border


@pytest.mark.parametrize("decimate", [2, 4])
def test_a_shrunk_detection_outlines_the_disc_in_the_frame_s_pixels(decimate: int) -> None:
    full = detect_spots_otsu(disc_image([(200, 180)])).spots[0]
    detection = detect_spots_otsu(disc_image([(200, 180)]), decimate=decimate)
    assert len(detection.spots) == 1
    spot = detection.spots[0]
    distances = np.hypot(spot.contour_px[:, 0] - 200, spot.contour_px[:, 1] - 180)
    assert distances.mean() == pytest.approx(40, abs=0.5 * decimate)  # within half a shrunk pixel
    # The outline runs half a shrunk pixel inside the spot; the area counts the strip it leaves out, and is then
    # the full frame's to within a quarter of a shrunk pixel along the outline (uncounted: 6 % short at 4).
    assert abs(spot.area_px - full.area_px) <= 2 * np.pi * 40 * decimate / 4
    assert detect_spots_otsu(disc_image([(390, 200)]), decimate=decimate).spots[0].touches_border
    with pytest.raises(ValueError, match="decimate"):
        detect_spots_otsu(disc_image([(200, 180)]), decimate=0)


@pytest.mark.parametrize(("decimate", "fine"), [(4, 2), (4, 1), (2, 1)])
def test_a_refined_detection_outlines_on_the_finer_frame_what_it_finds_on_the_coarser(decimate: int, fine: int) -> None:
    # Two discs (one cut by the border) on a broad glow: found on the frame shrunk by `decimate`, outlined again on
    # the frame shrunk by `fine` only around them, with the coarse pass's threshold and background. The outlines
    # are those of a detection on the finer frame alone, but for the threshold (Otsu's of another histogram).
    image = disc_image([(200, 180), (395, 60)], radius=30).astype(float)
    columns = np.arange(400)
    image += 60.0 * np.exp(-(((columns[None, :, None] - 120) / 150.0) ** 2))
    image = image.clip(0, 255).astype(np.uint8)
    options = {"blur_px": 3, "background_px": 200}
    alone = detect_spots_otsu(image, decimate=fine, **options)
    refined = detect_spots_otsu(image, decimate=decimate, refine=(fine, 3), **options)
    assert len(refined.spots) == len(alone.spots) == 2
    for spot, reference in zip(refined.spots, alone.spots, strict=True):
        centre = reference.contour_px.mean(axis=0)
        radius, expected = (np.hypot(*(s.contour_px - centre).T).mean() for s in (spot, reference))
        assert radius == pytest.approx(expected, abs=0.25)
        assert spot.area_px == pytest.approx(reference.area_px, rel=0.02)
        assert spot.touches_border == reference.touches_border
    assert refined.spots[1].touches_border
    with pytest.raises(ValueError, match="divide"):
        detect_spots_otsu(image, decimate=4, refine=(3, 3))


@pytest.mark.parametrize("row", [200, 201, 202, 203])
def test_a_refined_outline_follows_a_streak_the_coarse_pass_missed(row: int) -> None:
    # A 4 px bright streak leaving a disc: the coarse pass (one row of each 4) may miss it, and the box around the
    # disc would cut it; the box is widened until the outline ends inside it, as the finer detection alone sees it.
    image = disc_image([(150, 200)])[:, :, 0]
    image[row - 2 : row + 2, 150:380] = 200
    alone = detect_spots_otsu(image, blur_px=3, decimate=2).spots[0]
    refined = detect_spots_otsu(image, blur_px=3, decimate=4, refine=(2, 3)).spots[0]
    assert refined.contour_px[:, 0].max() == alone.contour_px[:, 0].max() > 370
    assert refined.area_px == pytest.approx(alone.area_px, rel=0.01)
    # A refine to the same shrink is no refine: the frame is read as without it.
    plain, same = (detect_spots_otsu(image, decimate=4, **options).spots[0] for options in ({}, {"refine": (4, 5)}))
    np.testing.assert_array_equal(same.contour_px, plain.contour_px)


def test_noise_alone_is_no_spot() -> None:
    assert detect_spots_otsu(disc_image([])).spots == ()


def test_two_discs_are_two_spots_largest_first() -> None:
    image = disc_image([(100, 100)], radius=30)
    cv2.circle(image, (300, 300), 45, (200, 200, 200), -1)
    spots = detect_spots_otsu(image).spots
    assert len(spots) == 2
    assert spots[0].area_px > spots[1].area_px


def test_cut_spot_touches_the_border() -> None:
    assert detect_spots_otsu(disc_image([(390, 200)])).spots[0].touches_border


def test_bit_depths_and_channels_agree() -> None:
    rgb = disc_image([(200, 200)])
    reference = detect_spots_otsu(rgb).spots[0].contour_px
    grey = rgb[..., 0]
    sixteen = grey.astype(np.uint16) * 257
    rgba = np.dstack([rgb, np.full(grey.shape, 255, np.uint8)])
    for variant in (grey, sixteen, rgba):
        np.testing.assert_array_equal(detect_spots_otsu(variant).spots[0].contour_px, reference)


@given(
    seed=st.integers(0, 2**31),
    shape=st.tuples(st.integers(1, 70), st.integers(1, 70)),
    spread=st.floats(0.5, 120.0),
)
def test_the_compiled_histograms_count_every_pixel_and_every_other_and_otsu_is_opencv_s(
    seed: int, shape: tuple[int, int], spread: float
) -> None:
    rng = np.random.default_rng(seed)
    image = rng.normal(rng.uniform(0, 255), spread, shape).clip(0, 255).astype(np.uint8)
    counts, sampled = _histograms(image)
    np.testing.assert_array_equal(counts, np.bincount(image.ravel(), minlength=256))
    np.testing.assert_array_equal(sampled, np.bincount(image[::2, ::2].ravel(), minlength=256))
    expected, _ = cv2.threshold(image, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    found = otsu_threshold(counts)
    # OpenCV's level, or one whose classes are as far apart: an exact tie, which OpenCV's build (Intel's IPP)
    # breaks its own way (9 pixels 161, 162 and 163, three of each: 161 here, 162 there).
    between = _between_class_variances(np.bincount(image.ravel(), minlength=256))
    assert found == int(expected) or between[found] == pytest.approx(between[int(expected)], rel=1e-12)
    assert between[found] == pytest.approx(between.max(), rel=1e-12)


def _between_class_variances(counts: np.ndarray) -> np.ndarray:
    """Otsu's criterion (256,) for each threshold level of a histogram, the levels up to it one class."""
    share = counts / counts.sum()
    below = np.cumsum(share)
    moment = np.cumsum(np.arange(256) * share)
    with np.errstate(divide="ignore", invalid="ignore"):
        variances = (moment[-1] * below - moment) ** 2 / (below * (1.0 - below))
    return np.nan_to_num(variances, nan=0.0, posinf=0.0)


def test_otsu_ties_are_broken_between_equally_good_levels() -> None:
    image = np.array([[162, 163, 162, 161, 162, 163, 163, 161, 161]], np.uint8)
    between = _between_class_variances(np.bincount(image.ravel(), minlength=256))
    assert otsu_threshold(_histograms(image)[0]) in (161, 162) and between[161] == pytest.approx(between[162])


def test_otsu_threshold_of_rendered_frames_is_opencv_s() -> None:
    # Two classes, a spot on a textured retina: the threshold OpenCV's THRESH_OTSU gives, level for level.
    setup = small_setup(512)
    renderer = Renderer(setup)
    for tip in ([0.5, -1.0, 4.0], [-1.5, 1.0, 7.0]):
        gray = to_gray8(renderer.render(InstrumentPose.through_insertion(tip, setup.instrument.insertion_in_eye)))
        expected, _ = cv2.threshold(gray, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        assert otsu_threshold(_histograms(gray)[0]) == int(expected)


@given(
    counts=st.lists(st.integers(0, 5000) | st.just(0), min_size=256, max_size=256),
    threshold=st.integers(0, 255),
)
def test_the_background_level_is_the_median_and_mad_of_the_levels_up_to_the_threshold(
    counts: list[int], threshold: int
) -> None:
    # Against the levels themselves (np.median's lower middle on a tie of two): the histogram's median is the level
    # where half the count is reached, its spread 1.4826 times the median absolute deviation.
    histogram = np.array(counts, dtype=np.int64)
    levels = np.repeat(np.arange(256), np.where(np.arange(256) <= threshold, histogram, 0))
    median, spread = _background_level(histogram, threshold)
    if len(levels) == 0:
        assert (median, spread) == (0, 0.0)
        return
    lower_median = int(np.sort(levels)[(len(levels) - 1) // 2])
    assert median == lower_median
    deviations = np.sort(np.abs(levels - lower_median))
    assert spread == 1.4826 * int(deviations[(len(deviations) - 1) // 2])


@settings(max_examples=200)
@given(
    seed=st.integers(0, 2**31),
    size=st.tuples(st.integers(1, 90), st.integers(1, 90)),
    disc_px=st.integers(0, 25).map(lambda half: 2 * half + 1),
    smooth=st.booleans(),
)
def test_the_padded_opening_is_opencv_s(seed: int, size: tuple[int, int], disc_px: int, smooth: bool) -> None:
    # Every bit, widths on both sides of the padded multiple, discs wider than the image: the pad takes no part.
    image = np.random.default_rng(seed).integers(0, 256, size=size, dtype=np.uint8)
    if smooth:
        image = cv2.GaussianBlur(image, (0, 0), 2.0)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (disc_px, disc_px))
    np.testing.assert_array_equal(_opening(image, disc), cv2.morphologyEx(image, cv2.MORPH_OPEN, disc))
