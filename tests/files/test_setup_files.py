from __future__ import annotations

import re
from dataclasses import fields, replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from spotnav.errors import SpotnavError
from spotnav.files.setup_files import CLAIMS_EXACT_GEOMETRY, read_opencv_camera, read_setup, setup_to_toml
from spotnav.setup.config import Setup, setup_from_toml
from spotnav.setup.examples import EXAMPLE_SETUP, EXAMPLES, MICROSCOPE_EXAMPLES
from spotnav.setup.sections import Bump, Instrument, World
from spotnav.setup.uncertainty import CalibrationRecord, Uncertainty
from spotnav.setup.values import SetupError

# The setup file as the contract writes it (shared/contract.md, "The setup file"), without [light].
CONTRACT_FILE = """\
[eye]
radius_mm = 12.5

[camera]
width_px = 5000
height_px = 5000
sensor_width_mm = 36.0
focal_length_mm = 300.0
distance_mm = 110.0

[instrument]
insertion_point_mm = [0.0, 6.0, 20.0]
beam_half_angle_deg = 9.0
beam_count = 1          # 1 or 3
beam_tilt_deg = 15.0    # used when beam_count > 1
"""
UNCERTAINTY_KEYS = [item.name for item in fields(Uncertainty)]


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


@pytest.mark.parametrize(
    ("cut_before", "missing"),
    [
        ("[camera]", "[camera], [instrument]"),
        ("[instrument]", "[instrument]"),
        ("distance_mm =", "camera.distance_mm, [instrument]"),
    ],
)
def test_a_setup_file_cut_short_names_what_it_lacks(tmp_path: Path, cut_before: str, missing: str) -> None:
    # Issue 61: a file cut after a complete section loaded with the rest silently defaulted ([instrument] among
    # them), and the user was then told to calibrate, not that the file was incomplete.
    path = tmp_path / "setup.toml"
    path.write_text(EXAMPLE_SETUP[: EXAMPLE_SETUP.index(cut_before)])
    with pytest.raises(SetupError) as error:
        read_setup(path)
    assert str(error.value).startswith(f"{path}: incomplete: no {missing} (")
    assert setup_from_toml(path.read_text()) == Setup()  # the Python API takes the thesis's values


def test_each_key_of_the_contract_is_required_of_a_setup_file(tmp_path: Path) -> None:
    # contract: [eye] radius_mm; [camera] the size and the ideal or the calibrated camera; [instrument] insertion
    # point, half-angle, beam count, and the tilt with three beams.
    path = tmp_path / "setup.toml"
    contract = "\n".join(line for line in CONTRACT_FILE.splitlines() if not line.startswith("#"))
    keys = [line.split("=")[0].strip() for line in contract.splitlines() if "=" in line]
    assert len(keys) == 10
    for key in keys[:-1]:  # beam_tilt_deg, last, is needed with more than one beam only
        path.write_text(re.sub(rf"(?m)^{key} =.*\n", "", contract))
        with pytest.raises(SetupError, match=rf"incomplete: no \w+\.{key} \("):
            read_setup(path, report=[].append)
    path.write_text(contract.replace("beam_tilt_deg", "# beam_tilt_deg"))
    assert read_setup(path, report=[].append) == Setup()
    calibrated = setup_to_toml(replace(Setup(), camera=Setup().camera.as_calibrated()))
    path.write_text(calibrated.replace("rotation = ", "# rotation = "))
    with pytest.raises(SetupError, match=r"camera\.rotation is missing: a calibrated camera gives camera\.matrix,"):
        read_setup(path)
    three = contract.replace("beam_count = 1", "beam_count = 3")
    path.write_text(three)
    assert read_setup(path, report=[].append).instrument.beam_count == 3
    path.write_text(three.replace("beam_tilt_deg", "# beam_tilt_deg"))
    with pytest.raises(SetupError, match=r"incomplete: no instrument\.beam_tilt_deg \("):
        read_setup(path)


def test_a_wrong_value_is_said_before_a_missing_key(tmp_path: Path) -> None:
    path = tmp_path / "setup.toml"
    path.write_text("[eye]\nradius = 12.5\n")  # a typo: the key's own name is the better message
    with pytest.raises(SetupError, match=r"eye\.radius is not a known key, allowed: radius_mm"):
        read_setup(path)


def test_the_uncertainty_a_setup_file_leaves_out_is_named_in_a_warning(tmp_path: Path) -> None:
    # The contract's file (as the Cycles sets give it) reads, with one warning: its geometry's uncertainty is a
    # typical microscope's, not its own, and decides which poses are refused as uncalibrated.
    path = tmp_path / "setup.toml"
    path.write_text(CONTRACT_FILE)
    warnings: list[str] = []
    assert read_setup(path, report=warnings.append) == Setup()
    (warning,) = warnings
    assert warning.startswith(f"spotnav: warning: {path} does not give [uncertainty]: assuming a typical microscope's")
    assert "edge_half_angle_deg 0.3, light_radius_mm 0.05, eye_radius_mm 0.25," in warning
    assert "until spotnav calibrate measures the geometry" in warning
    path.write_text(CONTRACT_FILE + "[uncertainty]\n" + "".join(f"{name} = 0.0\n" for name in UNCERTAINTY_KEYS[:-2]))
    warnings.clear()
    read_setup(path, report=warnings.append)
    (warning,) = warnings
    names = ", ".join(f"uncertainty.{name}" for name in UNCERTAINTY_KEYS[-2:])
    assert (
        f"does not give {names}: assuming a typical microscope's (insertion_point_mm 0.5, beam_tilt_deg 0.5)" in warning
    )


@pytest.mark.parametrize("examples", [EXAMPLES, MICROSCOPE_EXAMPLES])
@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_the_example_setups_read_without_a_warning(tmp_path: Path, examples: dict[str, str], name: str) -> None:
    path = tmp_path / "setup.toml"
    path.write_text(examples[name])
    warnings: list[str] = []
    assert read_setup(path, report=warnings.append) == setup_from_toml(examples[name])
    path.write_text(setup_to_toml(Setup(), "what setup_to_toml writes is whole"))
    assert read_setup(path, report=warnings.append) == Setup()
    assert warnings == []


def test_a_setup_that_claims_exact_geometry_is_told_so_when_it_is_to_answer_frames(tmp_path: Path) -> None:
    # Issue 62: a newcomer's frames from a world 0.5 deg wider in the beam and 0.5 mm higher in the camera, read with
    # the old `scene --example` (every [uncertainty] value 0), were 20/20 ok at 0.22 mm, none within 3 sigma, and no
    # word of warning. Now a setup that claims its geometry exactly, read to answer frames, says so in one line with
    # the way to a microscope's answers; read for anything else (render, calibrate) it says nothing.
    path = tmp_path / "setup.toml"
    path.write_text(EXAMPLE_SETUP)
    warnings: list[str] = []
    assert read_setup(path, report=warnings.append) == setup_from_toml(EXAMPLE_SETUP) and warnings == []
    read_setup(path, report=warnings.append, localizing=True)
    assert warnings == [f"spotnav: warning: {path} {CLAIMS_EXACT_GEOMETRY}"]
    assert "\n" not in warnings[0] and "leave [uncertainty] out" in warnings[0] and "spotnav calibrate" in warnings[0]


@pytest.mark.parametrize(
    "setup",
    [
        replace(setup_from_toml(EXAMPLE_SETUP), uncertainty=replace(Uncertainty.exact(), eye_radius_mm=0.01)),
        replace(setup_from_toml(EXAMPLE_SETUP), calibration=CalibrationRecord(("eye_radius_mm",), ((1e-4,),))),
        Setup(),
    ],
    ids=["one-value-stated", "calibrated", "a-microscope's"],
)
def test_a_setup_that_states_any_uncertainty_or_a_calibration_is_not_told(tmp_path: Path, setup: Setup) -> None:
    path = tmp_path / "setup.toml"
    path.write_text(setup_to_toml(setup, "a setup"))
    warnings: list[str] = []
    assert read_setup(path, report=warnings.append, localizing=True) == setup
    assert warnings == []


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
