"""What a calibration's frames determine, in words: units, and how well the frames pin a parameter."""

from __future__ import annotations

import pytest

from spotnav.pose.determined import DETERMINED_RATIO, _pinned, unit_of
from spotnav.setup.uncertainty import GEOMETRY_PARAMETERS


def test_every_geometry_parameter_has_a_printed_unit_but_the_distortion_coefficients() -> None:
    units = {name: unit_of(name) for name in GEOMETRY_PARAMETERS}
    assert units["camera_z_mm"] == "mm" and units["focal_length_percent"] == "%"
    assert units["camera_rotation_x_deg"] == "deg" and units["principal_point_u_px"] == "px"
    assert [name for name, unit in units.items() if not unit] == [n for n in GEOMETRY_PARAMETERS if "distortion" in n]


@pytest.mark.parametrize(
    ("ratio", "said"),
    [
        (27.25, "the frames pin it 27 times worse than the setup's stated +-0.5 mm"),
        (2.6, "the frames pin it 2.6 times worse than the setup's stated +-0.5 mm"),
        (0.43, f"the frames pin it to 0.43 of the setup's stated +-0.5 mm (a fit needs under {DETERMINED_RATIO:g})"),
    ],
)
def test_how_well_the_frames_pin_a_parameter_is_said_against_the_setup_s_uncertainty(ratio: float, said: str) -> None:
    assert _pinned(ratio, "+-0.5 mm") == said
