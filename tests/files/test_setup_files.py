from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from spotnav.errors import SpotnavError
from spotnav.files.setup_files import read_opencv_camera, read_setup, setup_to_toml
from spotnav.setup.config import Setup, setup_from_toml
from spotnav.setup.sections import Bump, Instrument, World
from spotnav.setup.values import SetupError


def test_read_setup_names_the_file(tmp_path: Path) -> None:
    with pytest.raises(SetupError, match="cannot read"):
        read_setup(tmp_path / "none.toml")
    (tmp_path / "bad.toml").write_text("[eye]\nradius_mm = -3\n")
    with pytest.raises(SetupError, match=r"bad\.toml: eye\.radius_mm"):
        read_setup(tmp_path / "bad.toml")


def test_a_byte_that_is_not_utf8_is_found_by_line_and_column(tmp_path: Path) -> None:
    # Issue 44: the message gave a byte position ("position 31"); a person finds a line and a column.
    path = tmp_path / "latin.toml"
    path.write_bytes(b"[eye]\nradius_mm = 12.5\n# r\xc3\xa9tine, caf\xe9\n")  # an accent in UTF-8, one in Latin-1
    with pytest.raises(SetupError) as error:
        read_setup(path)
    assert str(error.value) == f"{path}: line 3, column 14: byte 0xe9 is not UTF-8 (TOML files are UTF-8)"


def test_a_setup_without_the_camera_s_size_warns_of_the_size_assumed(tmp_path: Path) -> None:
    # The contract's keys take the thesis's values when missing (docs/setup.md), but the camera's size decides which
    # frames are read at all: every frame of a 512 px camera was wrong_size, silently.
    warnings: list[str] = []
    path = tmp_path / "setup.toml"
    path.write_text("[camera]\nheight_px = 512\n")
    assert read_setup(path, report=warnings.append).camera.width_px == 5000
    assert warnings == [
        f"spotnav: warning: {path} does not give the camera's size: assuming camera.width_px = 5000, the thesis's "
        "(frames that are not 5000x512 px are wrong_size)"
    ]
    path.write_text(setup_to_toml(Setup(), "complete"))
    read_setup(path, report=warnings.append)
    assert len(warnings) == 1


def test_setup_to_toml_round_trips() -> None:
    setups = [
        Setup(),
        Setup(
            world=World(eye_radius_mm=13.0, bumps=(Bump(1.0, -2.0),), surface="sphere"),
            instrument=Instrument(beam_count=3, edge_half_angle_deg=8.5, height_correction=1.03),
        ),
    ]
    for setup in setups:
        text = setup_to_toml(setup, "a header\nof two lines")
        assert text.startswith("# a header\n# of two lines\n")
        assert setup_from_toml(text) == setup


@pytest.mark.parametrize("suffix", [".yaml", ".xml", ".json"])
def test_an_opencv_calibration_is_read(tmp_path: Path, suffix: str) -> None:
    # As OpenCV's calibration sample writes it, through cv2.FileStorage.
    path = tmp_path / f"camera{suffix}"
    matrix = np.array([[8567.5, 0.0, 510.2], [0.0, 8570.1, 513.9], [0.0, 0.0, 1.0]])
    distortion = np.array([[-3.0, 0.5, 0.001, -0.002, 0.0]])
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("image_width", 1024)
    storage.write("image_height", 768)
    storage.write("camera_matrix", matrix)
    storage.write("distortion_coefficients", distortion)
    storage.release()
    width, height, read_matrix, read_distortion = read_opencv_camera(path)
    assert (width, height) == (1024, 768)
    np.testing.assert_array_equal(read_matrix, matrix)
    np.testing.assert_array_equal(read_distortion, distortion.ravel())


def test_an_opencv_file_without_the_keys_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "other.yaml"
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("camera_matrix", np.eye(3))
    storage.release()
    with pytest.raises(SpotnavError, match="no distortion_coefficients"):
        read_opencv_camera(path)
    with pytest.raises(SpotnavError, match="no such file"):
        read_opencv_camera(tmp_path / "missing.yaml")
    (tmp_path / "text.yaml").write_text("not: [a, calibration")
    with pytest.raises(SpotnavError, match=r"text\.yaml"):
        read_opencv_camera(tmp_path / "text.yaml")
