from __future__ import annotations

import cv2
import numpy as np
import pytest
from conftest import small_setup
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav.image.detect import (
    _BRANCHLESS_SELECT_MAX,
    _SMOOTHING,
    SpotDetection,
    _background_level,
    _brightest_channel,
    _decoding,
    _histograms,
    _linear_crop,
    _long_runs,
    _median,
    _near_hull,
    _one_row_means,
    _opening,
    _shrunk_gray,
    _smooth,
    detect_edge_along_rays,
    detect_edge_subpixel,
    detect_spots_otsu,
    edge_window_px,
    group_fragments,
    linear_luminance,
    otsu_threshold,
    outer_boundary,
    rays_through_curve,
    to_gray8,
)
from spotnav.image.photometry import edge_light
from spotnav.optics.camera import decoding_table, encoding_table, unproject_pixels_to_sphere
from spotnav.optics.pixelnoise import new_noise_pool
from spotnav.optics.render import Renderer
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose, angles_between, edge_angle_of_blend


def disc_image(centers: list[tuple[int, int]], radius: int = 40, size: int = 400, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    image = rng.normal(15, 2, (size, size)).clip(0, 255).astype(np.uint8)
    for center in centers:
        cv2.circle(image, center, radius, 200, -1)
    return np.dstack([image] * 3)


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


def test_a_tone_curve_clips_where_it_writes_full_scale_and_another_channel_is_read() -> None:
    # AgX-like writes light at full scale as 242 of 255: a red channel there is clipped, green is read.
    light = np.array([1.0, 0.25, 0.1])
    codes = encoding_table("agx", 8)[np.round(light * 65535).astype(int)]
    assert codes[0] == _decoding(codes[None], "agx")[1] == encoding_table("agx", 8)[-1] < 255
    image = np.broadcast_to(codes, (20, 20, 3)).copy()
    lut, full_scale = _decoding(image, "agx")
    pixels, centre, saturated, channel = _linear_crop(image, full_scale, np.array([10.0, 10.0]), 5.0)
    assert saturated and channel == 1 and lut[full_scale] == decoding_table("agx", 8)[codes[0]]
    np.testing.assert_array_equal(lut[pixels], decoding_table("agx", 8)[codes[1]])
    assert pixels.shape == (13, 13) and np.array_equal(centre, [6.0, 6.0])  # pixels 4 to 16: 5 px each way, and more
    assert _decoding(codes[None], "srgb")[1] == 254  # sRGB: the first code that decodes to 0.99


def test_to_gray8_rejects_other_types() -> None:
    with pytest.raises(ValueError, match="8-bit or 16-bit"):
        to_gray8(np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match="grey, RGB or RGBA"):
        to_gray8(np.zeros((4, 4, 2), np.uint8))


def _edge_angles(setup: Setup, pose: InstrumentPose, image: np.ndarray, max_rays: int = 2048) -> np.ndarray:
    spot = detect_spots_otsu(image).spots[0]
    edge = detect_edge_subpixel(image, spot, max_rays=max_rays)
    assert edge.rays == min(max_rays, int(cv2.arcLength(spot.contour_px.astype(np.float32), True)))
    assert len(edge.pixels) > 0.9 * edge.rays
    points = unproject_pixels_to_sphere(setup.camera, edge.pixels, setup.eye.radius_mm)
    return np.degrees(angles_between(points - pose.tip_in_eye, pose.axis))


@pytest.mark.parametrize("blend", [0.0, 0.15])
def test_subpixel_edge_sits_at_the_half_light_angle(blend: float) -> None:
    # Flat albedo, no noise: the edge lies at the model's angle within 0.002 deg (a 1 um height error
    # at 4.5 mm; the precise method's budget is 5 um), even at 1024 px where a pixel spans 0.3 deg.
    setup = small_setup(1024, blend=blend, texture="flat", full_well_e=0.0)
    pose = InstrumentPose.through_insertion([1.0, -1.5, 4.5], setup.instrument.insertion_in_eye)
    angles = _edge_angles(setup, pose, Renderer(setup).render(pose))
    model = np.degrees(edge_angle_of_blend(setup.instrument.beam_half_angle, blend))
    assert abs(angles.mean() - model) < 0.002
    assert angles.std() < 0.01


def test_subpixel_edge_on_fewer_rays_sits_alike() -> None:
    # The precise method reads at most 256 rays a spot: 64 rays (of some 340) find the same edge angle within
    # 0.002 deg; fewer than 64 are refused.
    setup = small_setup(1024, blend=0.15, texture="flat", full_well_e=0.0)
    pose = InstrumentPose.through_insertion([1.0, -1.5, 4.5], setup.instrument.insertion_in_eye)
    image = Renderer(setup).render(pose)
    assert abs(_edge_angles(setup, pose, image, 64).mean() - _edge_angles(setup, pose, image).mean()) < 0.002
    with pytest.raises(ValueError, match="at least 64"):
        detect_edge_subpixel(image, detect_spots_otsu(image).spots[0], max_rays=63)


def test_subpixel_edge_holds_its_place_over_power_and_saturation() -> None:
    # 0.1 W to 2 W (the red channel clips at 2 W) on the textured retina: the mean edge angle moves
    # by under 0.003 deg, while Otsu's moves by almost 0.1 deg.
    setup = small_setup(2048, blend=0.15)
    pose = InstrumentPose.through_insertion([1.0, -1.5, 4.5], setup.instrument.insertion_in_eye)
    renderer = Renderer(setup)
    means = [_edge_angles(setup, pose, renderer.render(pose, power_w=p, seed=1)).mean() for p in (0.1, 0.5, 2.0)]
    assert np.ptp(means) < 0.003
    bright = renderer.render(pose, power_w=2.0)
    assert detect_edge_subpixel(bright, detect_spots_otsu(bright).spots[0]).saturated


def test_linear_luminance_inverts_srgb() -> None:
    codes = np.array([[0, 10, 128, 255]], dtype=np.uint8)
    linear = linear_luminance(codes)
    np.testing.assert_allclose(linear[0, [0, 3]], [0.0, 1.0], atol=1e-7)
    assert linear[0, 2] == pytest.approx(0.2158605, rel=1e-5)
    rgb = np.repeat(codes[..., None], 3, axis=2)
    np.testing.assert_allclose(linear_luminance(rgb), linear, rtol=1e-6)


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


@settings(max_examples=80)
@given(
    seed=st.integers(0, 2**31),
    decimate=st.sampled_from([3, 4, 5, 8, 16, 32]),
    channels=st.sampled_from([0, 1, 3, 4]),
    bits=st.sampled_from([8, 16]),
    size=st.tuples(st.integers(40, 90), st.integers(40, 90)),  # a cell of 32 after the crop
    view=st.sampled_from(["whole", "reversed channels", "cropped"]),
)
def test_one_row_of_each_cell_is_opencv_s_resize_of_those_rows(
    seed: int, decimate: int, channels: int, bits: int, size: tuple[int, int], view: str
) -> None:
    dtype = np.uint8 if bits == 8 else np.uint16
    shape = size if channels == 0 else (*size, channels)
    image = np.random.default_rng(seed).integers(0, 2**bits, size=shape).astype(dtype)
    if view == "reversed channels" and channels > 1:
        image = image[..., ::-1]
    elif view == "cropped":
        image = image[1:, 3:]
    height, width = image.shape[0] // decimate, image.shape[1] // decimate
    rows = np.ascontiguousarray(image[: height * decimate, : width * decimate][decimate // 2 - 1 :: decimate])
    expected = cv2.resize(rows, (width, height), interpolation=cv2.INTER_LINEAR)
    if expected.ndim == 2:
        expected = expected[:, :, None]
    cells = np.empty_like(expected)
    _one_row_means(image.reshape(*image.shape[:2], -1), decimate, (0,) * expected.shape[2], cells, False)
    np.testing.assert_array_equal(cells, expected)  # every bit, before the grey conversion
    for response in ("srgb", "linear"):  # the first made grey in the same pass, the second after it
        grey = to_gray8(expected[:, :, 0] if channels <= 1 else expected, response)
        np.testing.assert_array_equal(_shrunk_gray(image, decimate, response, one_row=True), grey)


def test_the_one_row_grey_is_opencv_s_on_its_ties_and_every_16_bit_level() -> None:
    # Random frames seldom meet a tie of the 15-bit weights (one colour in 32768) or of the 16 to 8 bit rounding:
    # every colour whose weighted sum is halfway, beside random ones, and every 16-bit level (cells of 4 x 4 pixels).
    # Against this OpenCV's cvtColor: a build that rounds otherwise (another hardware library) fails here.
    levels = np.arange(256)
    r, g, b = (v.ravel() for v in np.meshgrid(levels, levels, levels, indexing="ij"))
    halfway = (9798 * r + 19235 * g + 3735 * b) % 32768 == 16384
    colours = np.stack([r, g, b], axis=1)[halfway | (np.arange(len(r)) % 4099 == 0)].astype(np.uint8)
    assert halfway.sum() > 100
    frame = np.repeat(np.repeat(colours[None], 4, axis=0), 4, axis=1)
    expected = cv2.cvtColor(colours[None], cv2.COLOR_RGB2GRAY)
    np.testing.assert_array_equal(_shrunk_gray(frame, 4, "srgb", one_row=True), expected)
    wide = np.repeat(np.repeat(np.arange(65536, dtype=np.uint16)[None], 4, axis=0), 4, axis=1)
    np.testing.assert_array_equal(_shrunk_gray(wide, 4, "srgb", one_row=True), to_gray8(wide[:1, ::4]))


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


@given(values=st.lists(st.integers(-5, 5) | st.floats(-1e6, 1e6), min_size=1, max_size=150))
def test_the_compiled_median_is_numpy_s(values: list[float]) -> None:
    # Both selections: without branches up to _BRANCHLESS_SELECT_MAX values, Hoare's past it; ties among them.
    array = np.array(values, dtype=float)
    assert _median(array, np.empty(len(array))) == np.median(array)
    scratch = array.copy()
    assert _median(scratch, scratch) == np.median(array)  # selected in place, as the edge reader's noise is


@pytest.mark.parametrize("count", [_BRANCHLESS_SELECT_MAX, _BRANCHLESS_SELECT_MAX + 1, 2000])
def test_a_median_among_many_equal_values_is_numpy_s(count: int) -> None:
    # Steps between clipped samples: mostly zeros, on both sides of the selection's switch.
    array = np.zeros(count)
    array[::7] = np.arange(len(array[::7])) - 3.0
    assert _median(array, np.empty(count)) == np.median(array)


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


@given(seed=st.integers(0, 2**31), length=st.integers(9, 80))
def test_compiled_smoothing_is_opencvs_reflected_gaussian(seed: int, length: int) -> None:
    values = np.random.default_rng(seed).normal(size=length)
    expected = cv2.GaussianBlur(values[None, :], (17, 1), 2.0, borderType=cv2.BORDER_REFLECT)[0]
    padded, out = np.empty(length + len(_SMOOTHING)), np.empty(length)
    np.testing.assert_allclose(_smooth(values, _SMOOTHING, 0, length, padded, out), expected, atol=1e-12)
    # Only samples 3 .. length - 3, into the same buffers: every padded sample it reads is its own (a stale one
    # would be NaN).
    padded[:] = np.nan
    part = _smooth(values, _SMOOTHING, 3, length - 2, padded, out)
    np.testing.assert_allclose(part[3 : length - 2], expected[3 : length - 2], atol=1e-12)
    assert np.isnan(part[:3]).all() and np.isnan(part[length - 2 :]).all()
    for start, stop in ((5, -2), (length, length + 4), (length + 3, length + 9), (-4, 0)):  # nothing to compute
        assert np.isnan(_smooth(values, _SMOOTHING, start, stop, padded, out)).all()


@settings(max_examples=30)
@given(
    centre=st.tuples(st.floats(-50, 50), st.floats(-50, 50)),
    radii=st.tuples(st.floats(5, 40), st.floats(5, 40)),
    tilt=st.floats(-np.pi, np.pi),
    rays=st.integers(8, 300),
)
def test_rays_through_an_ellipse_meet_it(centre: tuple, radii: tuple, tilt: float, rays: int) -> None:
    # Rays from an ellipse's centre meet its curve (720 points) where the ellipse is, to its sampling's error.
    angles = np.linspace(0.0, 2.0 * np.pi, 720, endpoint=False)
    local = np.column_stack([radii[0] * np.cos(angles), radii[1] * np.sin(angles)])
    turn = np.array([[np.cos(tilt), -np.sin(tilt)], [np.sin(tilt), np.cos(tilt)]])
    curve = np.asarray(centre) + local @ turn.T
    found, ray_angles, distances = rays_through_curve(curve, rays)
    np.testing.assert_allclose(found, centre, atol=1e-9)
    assert len(ray_angles) == rays and ray_angles[0] == -np.pi
    points = (np.column_stack([np.cos(ray_angles), np.sin(ray_angles)]) * distances[:, None]) @ turn
    on_ellipse = np.hypot(points[:, 0] / radii[0], points[:, 1] / radii[1])
    np.testing.assert_allclose(on_ellipse, 1.0, atol=2e-3)
    with pytest.raises(ValueError, match="N >= 1"):
        rays_through_curve(np.zeros((0, 2)), rays)


def test_rays_must_be_finite_and_one_per_radius() -> None:
    image = disc_image([(200, 200)])
    angles, radii = np.linspace(-np.pi, np.pi, 64, endpoint=False), np.full(64, 40.0)
    assert len(detect_edge_along_rays(image, np.array([200.0, 200.0]), angles, radii).pixels) > 60
    for centre, these in (([np.nan, 200.0], radii), ([200.0, 200.0], np.append(radii[1:], np.inf))):
        with pytest.raises(ValueError, match="finite"):
            detect_edge_along_rays(image, np.array(centre), angles, these, align=True)
    with pytest.raises(ValueError, match="centre must be"):
        detect_edge_along_rays(image, np.array([200.0, 200.0]), angles, radii[:-1])
    for pool in (np.zeros((4, 2)), np.zeros((4, 2, 3)), new_noise_pool().astype(np.float32)):
        with pytest.raises(ValueError, match="noise_pool"):
            detect_edge_along_rays(image, np.array([200.0, 200.0]), angles, radii, noise_pool=pool)
    assert edge_window_px([10.0, 20.0]) == edge_window_px(np.array([10.0, 20.0])) == 0.15 * 15.0 + 8.0


@pytest.mark.parametrize("offset_px", [(0.0, 0.0), (4.0, -3.0), (-9.0, 6.0)])
def test_aligned_rays_find_a_disc_that_moved_since_the_prediction(offset_px: tuple[float, float]) -> None:
    """A disc of radius 60 px at (200.3, 199.6); the rays are cast around a circle of radius 64 px moved by
    ``offset_px``: with ``align`` every edge point lies on the disc's true rim."""
    size, centre, radius = 400, np.array([200.3, 199.6]), 60.0
    rows, columns = np.mgrid[:size, :size]
    distance = np.hypot(columns - centre[0], rows - centre[1])
    light = 0.02 + 0.6 / (1.0 + np.exp((distance - radius) / 0.8))  # a soft edge, linear light
    image = np.dstack(
        [np.round(255 * np.where(light <= 0.0031308, 12.92 * light, 1.055 * light ** (1 / 2.4) - 0.055))] * 3
    )
    angles = np.linspace(0.0, 2.0 * np.pi, 200, endpoint=False)
    predicted = centre + np.array(offset_px) + 64.0 * np.column_stack([np.cos(angles), np.sin(angles)])
    edge = detect_edge_along_rays(image.astype(np.uint8), *rays_through_curve(predicted, 160), align=True)
    assert len(edge.pixels) >= 0.95 * edge.rays
    rim = np.hypot(*(edge.pixels - centre).T)
    assert np.abs(rim - radius).max() < 0.15


def _fragments_of(image: np.ndarray, gap_px: float = 12.0, whole_area_px: float = 1500.0) -> SpotDetection:
    return group_fragments(detect_spots_otsu(image, min_area_fraction=0.005), image.shape[:2], gap_px, whole_area_px)


def test_a_spot_cut_by_vessels_is_one_spot() -> None:
    # Three dark lines across one disc leave six fragments; their outer boundaries lie on one circle.
    image = disc_image([(200, 200)], radius=60)
    for angle in (0.3, 1.4, 2.5):
        direction = 90 * np.array([np.cos(angle), np.sin(angle)])
        cv2.line(image, tuple((200 - direction).astype(int)), tuple((200 + direction).astype(int)), (15,) * 3, 6)
    assert len(detect_spots_otsu(image, min_area_fraction=0.005).spots) == 6
    grouped = _fragments_of(image)
    assert len(grouped.spots) == 1 and grouped.fragments == 6 and grouped.regions == "6 bright regions in 1 spot"
    distances = np.hypot(*(grouped.spots[0].contour_px - 200).T)  # whole pixels of a blurred, thresholded disc
    assert np.abs(distances.mean() - 60) < 1.0 and np.abs(distances - 60).max() < 3.0
    assert grouped.spots[0].area_px == pytest.approx(np.pi * 60**2, rel=0.05)


def test_separate_spots_and_a_glint_beside_a_spot_stay_apart() -> None:
    # Two whole discs 10 px apart (closer than the gap) are two spots; a glint 10 px beside one (within the
    # gap too) is not part of it: the disc's outline stays the circle's.
    image = disc_image([(140, 200), (240, 200)], radius=45)
    cv2.circle(image, (140, 140), 5, (255, 255, 255), -1)
    grouped = _fragments_of(image, whole_area_px=1000.0)
    assert [round(s.area_px / (np.pi * 45**2), 1) for s in grouped.spots[:2]] == [1.0, 1.0]
    for spot in grouped.spots[:2]:
        centre = (140, 200) if spot.contour_px[:, 0].mean() < 190 else (240, 200)
        assert np.hypot(*(spot.contour_px - centre).T).max() < 47
    assert len(grouped.spots) == 2  # the glint is clutter beside them


def test_edge_points_where_vessels_cross_the_edge_are_left_out() -> None:
    # Two dark vessels cross a disc's edge obliquely: the rays on them and beside them are left out (and
    # counted), and the edge points found lie on the circle (cv2's disc is jagged by half a pixel; the
    # vessels' corners pull points in by up to 7 px when the rays beside them are kept).
    image = disc_image([(200, 200)], radius=60)
    for start, end in (((150, 150), (290, 230)), ((120, 260), (230, 110))):
        cv2.line(image, start, end, (15, 15, 15), 7)
    edge = detect_edge_subpixel(image, outer_boundary(_fragments_of(image).spots[0]))
    assert edge.dark_rays > 0.04 * edge.rays
    off = np.abs(np.hypot(*(edge.pixels - 200).T) - 60)
    assert np.percentile(off, 95) < 1.0 and off.max() < 2.0


@pytest.mark.parametrize("size_px", [90, 700])
def test_the_brightest_channel_that_never_clips_is_read(size_px: int) -> None:
    # Red clips over a patch of 5 % of the crop, green is bright and never clips, blue is dim. On a large crop the
    # channels are judged on a sparser grid, which still meets the patch.
    crop = np.zeros((size_px, size_px, 3), np.uint8)
    crop[..., 0], crop[..., 1], crop[..., 2] = 120, 200, 60
    side = int(0.22 * size_px)
    crop[size_px // 3 : size_px // 3 + side, size_px // 2 : size_px // 2 + side, 0] = 255
    assert _brightest_channel(crop, 255) == (1, True)
    crop[..., 0] = 230  # red now the brightest, and nothing clips
    assert _brightest_channel(crop, 255) == (0, False)


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
