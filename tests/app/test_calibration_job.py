from __future__ import annotations

from pathlib import Path

import pytest
from test_cli import write_scene

from spotnav.app.calibration_job import run_calibration
from spotnav.errors import SpotnavError
from spotnav.files.setup_files import read_setup


def test_calibrate_rejects_unusable_input(tmp_path: Path) -> None:
    setup = read_setup(write_scene(tmp_path / "setup.toml", size_px=256))
    known = tmp_path / "known.csv"
    known.write_text("image,x_mm,y_mm,z_mm\na.png,1,1,4\n")
    with pytest.raises(SpotnavError, match="at least 3 usable frames"):
        run_calibration(setup, known)
    with pytest.raises(SpotnavError, match="is not in"):
        run_calibration(setup, known, [str(tmp_path / "other.png")])
    known.write_text("image,x_mm\na.png,1\n")
    with pytest.raises(SpotnavError, match="needs a header"):
        run_calibration(setup, known)
    video_truth = tmp_path / "helix.truth.csv"
    video_truth.write_text("frame,image,x_mm,y_mm,z_mm\n0,,0,0,4\n1,,0,0,4.5\n2,,0,0,5\n")
    with pytest.raises(SpotnavError, match="names a video's frames"):
        run_calibration(setup, video_truth)
