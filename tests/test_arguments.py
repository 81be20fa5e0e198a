from __future__ import annotations

import pytest

from spotnav import arguments
from spotnav.app import igtl
from spotnav.experiments import EXPERIMENTS
from spotnav.pose.conefit.parameters import PARAMETER_GROUPS
from spotnav.pose.localize import DEFAULT_METHOD, METHODS


def test_the_parser_offers_the_names_the_library_defines() -> None:
    # The parser imports the standard library only, so it writes the names out: they must be the library's.
    assert arguments.METHODS == tuple(METHODS) and arguments.DEFAULT_METHOD == DEFAULT_METHOD
    assert arguments.PARAMETER_GROUPS == tuple(PARAMETER_GROUPS)
    assert arguments.EXPERIMENTS == tuple(EXPERIMENTS)
    assert (arguments.DEFAULT_PORT, arguments.DEFAULT_HOST, arguments.DEFAULT_DEVICE) == (
        igtl.DEFAULT_PORT,
        igtl.DEFAULT_HOST,
        igtl.DEFAULT_DEVICE,
    )


def test_the_parser_takes_those_names(capsys: pytest.CaptureFixture[str]) -> None:
    parser = arguments.build_parser("spotnav")
    calibrate = ["calibrate", "--scene", "s.toml", "--poses", "k.csv", "--out", "c.toml"]
    assert parser.parse_args([*calibrate, "--fit", "focal-length"]).fit == ["focal-length"]
    assert parser.parse_args(["reproduce", "--only", "mismatch"]).only == ["mismatch"]
    assert parser.parse_args(["track", "--scene", "s", "v.mkv", "--out", "p", "--igtl"]).igtl == igtl.DEFAULT_PORT
    with pytest.raises(SystemExit):
        parser.parse_args(["localize", "--scene", "s", "--method", "nope", "f.png", "--out", "p"])
    assert "invalid choice" in capsys.readouterr().err
