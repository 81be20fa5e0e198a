from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from spotnav.files.images import ImageReadError, image_size, read_image, write_image


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
    cases = {"missing.png": "no such file", "empty.png": "empty", "text.png": "not an image", "cut.png": "not an image"}
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
