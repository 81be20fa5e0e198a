"""A frame's values as grey levels and light: the grey image, the shrunk cells, the decoding and the channel read."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav.image.channels import (
    _brightest_channel,
    _decoding,
    _linear_crop,
    _one_row_means,
    _shrunk_gray,
    linear_luminance,
    to_gray8,
)
from spotnav.optics.response import decoding_table, encoding_table


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


def test_linear_luminance_inverts_srgb() -> None:
    codes = np.array([[0, 10, 128, 255]], dtype=np.uint8)
    linear = linear_luminance(codes)
    np.testing.assert_allclose(linear[0, [0, 3]], [0.0, 1.0], atol=1e-7)
    assert linear[0, 2] == pytest.approx(0.2158605, rel=1e-5)
    rgb = np.repeat(codes[..., None], 3, axis=2)
    np.testing.assert_allclose(linear_luminance(rgb), linear, rtol=1e-6)


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
