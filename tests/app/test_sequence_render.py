from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import small_setup
from test_cli import read_poses, write_scene

from spotnav.app.sequence_render import check_inside, render_sequence
from spotnav.errors import SpotnavError
from spotnav.files.setup_files import read_setup


def test_render_a_csv_path_to_png_frames(tmp_path: Path) -> None:
    setup = read_setup(write_scene(tmp_path / "setup.toml", size_px=256))
    waypoints = tmp_path / "path.csv"
    waypoints.write_text("x_mm,y_mm,z_mm\n0,0,4\n1,0,4\n1,1,5\n")
    rendered = render_sequence(setup, str(waypoints), tmp_path / "f", frames=5, fps=100.0, tremor_mm=0.0, seed=0)
    assert (rendered.frames, rendered.out, rendered.truth) == (5, tmp_path / "f", tmp_path / "f" / "truth.csv")
    truth = read_poses(tmp_path / "f" / "truth.csv")
    assert [r["image"] for r in truth] == [f"frame_{i:05d}.png" for i in range(5)]
    assert all((tmp_path / "f" / r["image"]).is_file() for r in truth)
    assert [float(truth[0]["x_mm"]), float(truth[-1]["z_mm"])] == [0.0, 5.0]


@pytest.mark.parametrize(
    ("frames", "fps", "tremor_mm", "message"),
    [
        (1, 100.0, 0.0, "--frames must be at least 2"),
        (5, float("nan"), 0.0, "--fps must be a finite number > 0"),
        (5, 100.0, float("nan"), "--tremor must be in"),
    ],
)
def test_unusable_sequences_are_user_errors(
    tmp_path: Path, frames: int, fps: float, tremor_mm: float, message: str
) -> None:
    setup = read_setup(write_scene(tmp_path / "setup.toml", size_px=256))
    with pytest.raises(SpotnavError, match=message):
        render_sequence(setup, "helix", tmp_path / "out", frames=frames, fps=fps, tremor_mm=tremor_mm, seed=0)


def test_a_tip_outside_the_eye_is_named() -> None:
    with pytest.raises(SpotnavError, match="a path's tip 0 0 40 lies outside the eye"):
        check_inside(small_setup(256), np.array([0.0, 0.0, 40.0]), "a path's tip")
