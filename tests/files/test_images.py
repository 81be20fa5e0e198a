from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from spotnav.files.images import MAX_IMAGE_BYTES, ImageReadError, image_size, read_image, write_image


def test_rgb_round_trip(tmp_path: Path) -> None:
    rgb = np.zeros((8, 9, 3), np.uint8)
    rgb[..., 0] = 200  # red
    write_image(tmp_path / "a.png", rgb)
    back = read_image(tmp_path / "a.png")
    np.testing.assert_array_equal(back, rgb)


@pytest.mark.parametrize(
    ("array", "shape", "dtype"),
    [
        (np.full((6, 7), 40000, np.uint16), (6, 7), np.uint16),
        (np.full((6, 7), 40, np.uint8), (6, 7), np.uint8),
        (np.full((6, 7, 4), 40, np.uint8), (6, 7, 4), np.uint8),
    ],
)
def test_grey_16_bit_and_rgba_are_read(tmp_path: Path, array: np.ndarray, shape: tuple, dtype: type) -> None:
    cv2.imwrite(str(tmp_path / "x.png"), array)
    image = read_image(tmp_path / "x.png")
    assert image.shape == shape and image.dtype == dtype


def test_bad_images_raise_one_line_errors(tmp_path: Path) -> None:
    (tmp_path / "empty.png").write_bytes(b"")
    (tmp_path / "text.png").write_text("not an image")
    cv2.imwrite(str(tmp_path / "good.png"), np.full((64, 64, 3), 90, np.uint8))
    data = (tmp_path / "good.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    cases = {"missing.png": "no such file", "empty.png": "empty", "text.png": "not an image"}
    cases["cut.png"] = "truncated PNG"
    for name, message in cases.items():
        with pytest.raises(ImageReadError, match=message) as error:
            read_image(tmp_path / name)
        assert name in str(error.value) and "\n" not in str(error.value)


def test_an_image_is_sized_from_its_header_before_it_is_decoded(tmp_path: Path) -> None:
    good = tmp_path / "good.png"
    cv2.imwrite(str(good), np.full((48, 64, 3), 90, np.uint8))
    assert image_size(good) == (64, 48)
    with pytest.raises(ImageReadError, match="image is 64x48 px, the setup's camera is 64x64 px") as error:
        read_image(good, expected_size=(64, 64))
    assert error.value.status == "wrong_size"
    assert read_image(good, expected_size=(64, 48)).shape == (48, 64, 3)
    with pytest.raises(ImageReadError, match="64x48 px would take more than") as error:
        read_image(good, max_bytes=8 * 64 * 48 - 1)
    assert error.value.status == "unreadable"


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=400), prefix=st.sampled_from([b"", b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff"]))
def test_random_bytes_read_as_an_image_or_a_one_line_error(tmp_path: Path, data: bytes, prefix: bytes) -> None:
    path = tmp_path / "random.png"
    path.write_bytes(prefix + data)
    try:
        image = read_image(path)
    except ImageReadError as error:
        assert "random.png" in str(error) and "\n" not in str(error)
    else:
        assert image.dtype in (np.uint8, np.uint16) and image.ndim in (2, 3)


def _png_header(width: int, height: int) -> bytes:
    """A PNG that is only its header: ``width`` x ``height`` RGB pixels claimed, none given."""
    ihdr = b"IHDR" + struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    chunk = struct.pack(">I", 13) + ihdr + struct.pack(">I", zlib.crc32(ihdr))
    return b"\x89PNG\r\n\x1a\n" + chunk + b"\x00\x00\x00\x00IEND\xaeB`\x82"


def test_one_rule_for_oversized_images_whatever_their_size(tmp_path: Path) -> None:
    # Issue 44: a 20000 px header was `unreadable` ("header claims over 178956970 pixels", Pillow's own limit) where a
    # 10000 px one was `wrong_size`. Now every size is read from the header and judged by one rule, before decoding.
    # 12000 px was below Pillow's limit (178956970 px) and 20000 px above it; both are over 1 GB decoded.
    for side in (10_000, 12_000, 20_000, 100_000):
        path = tmp_path / f"{side}.png"
        path.write_bytes(_png_header(side, side))
        assert image_size(path) == (side, side)
        with pytest.raises(ImageReadError) as error:
            read_image(path, expected_size=(5000, 5000))
        assert error.value.status == "wrong_size"
        assert str(error.value) == f"{path}: image is {side}x{side} px, the setup's camera is 5000x5000 px"
        if 8 * side**2 <= MAX_IMAGE_BYTES:
            continue
        with pytest.raises(ImageReadError) as error:  # no camera to compare with: too large to decode
            read_image(path)
        assert error.value.status == "unreadable"
        limit = MAX_IMAGE_BYTES >> 20
        assert str(error.value) == f"{path}: {side}x{side} px would take more than {limit} MB"


def _cut(tmp_path: Path, suffix: str, keep: float) -> Path:
    whole = tmp_path / f"whole{suffix}"
    cv2.imwrite(str(whole), np.random.default_rng(0).integers(0, 255, (128, 128, 3), dtype=np.uint8))
    data = whole.read_bytes()
    cut = tmp_path / f"cut-{keep}{suffix}"
    cut.write_bytes(data[: int(len(data) * keep)])
    return cut


@pytest.mark.parametrize("keep", [0.02, 0.5, 0.99])
def test_a_truncated_png_is_named_as_such_and_libpng_stays_quiet(
    tmp_path: Path, keep: float, capfd: pytest.CaptureFixture[str]
) -> None:
    # libpng printed "PNG input buffer is incomplete" (and OpenCV its own warning) on stderr, and the row said
    # "not an image OpenCV can read (or truncated, or too large)".
    cut = _cut(tmp_path, ".png", keep)
    with pytest.raises(ImageReadError, match=r"truncated PNG: the file ends after \d+ bytes") as error:
        read_image(cut)
    assert error.value.status == "unreadable" and str(error.value).startswith(str(cut))
    assert capfd.readouterr().err == ""


def test_a_png_with_bytes_after_its_end_still_reads(tmp_path: Path) -> None:
    whole = _cut(tmp_path, ".png", 1.0)
    whole.write_bytes(whole.read_bytes() + b"trailing bytes")
    assert read_image(whole).shape == (128, 128, 3)


@pytest.mark.parametrize("suffix", [".tif", ".jpg"])
def test_other_damaged_images_fail_without_library_noise(
    tmp_path: Path, suffix: str, capfd: pytest.CaptureFixture[str]
) -> None:
    # OpenCV's TIFF errors and Pillow's warnings about a damaged header went to stderr too.
    cut = _cut(tmp_path, suffix, 0.5)
    with pytest.raises(ImageReadError, match=r"cannot be decoded|not an image OpenCV can read") as error:
        read_image(cut)
    assert error.value.status == "unreadable"
    assert capfd.readouterr().err == ""
