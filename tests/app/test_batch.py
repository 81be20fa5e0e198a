from __future__ import annotations

from pathlib import Path

import pytest
from test_cli import read_poses, write_scene

from spotnav.app.batch import localize_batch
from spotnav.cli import main
from spotnav.errors import SpotnavError
from spotnav.files.setup_files import read_setup


def test_localize_keeps_going_past_bad_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene = write_scene(tmp_path / "setup.toml", size_px=384)
    good = tmp_path / "good.png"
    assert main(["render", "--scene", str(scene), "--tip", "0", "0", "4", "--out", str(good)]) == 0
    dark = tmp_path / "dark.png"
    assert main(["render", "--scene", str(scene), "--tip", "0", "0", "4", "--power", "0", "--out", str(dark)]) == 0
    (tmp_path / "empty.png").write_bytes(b"")
    images = [str(good), str(tmp_path / "missing.png"), str(tmp_path / "empty.png"), str(dark)]
    batch = localize_batch(images, read_setup(scene), "precise", tmp_path / "poses.csv")
    rows = read_poses(tmp_path / "poses.csv")
    assert [r["image"] for r in rows] == images
    assert [r["status"] for r in rows] == ["ok", "unreadable", "unreadable", "no_spot"]
    assert all(r["x_mm"] == "" for r in rows[1:])
    err = capsys.readouterr().err
    assert "missing.png: no such file" in err
    assert batch.rows == 4 and batch.statuses == {"ok": 1, "unreadable": 2, "no_spot": 1}
    assert batch.stopped_by is None and batch.radius is None


def test_localize_fit_radius_needs_the_precise_method_and_20_frames(tmp_path: Path) -> None:
    scene = write_scene(tmp_path / "setup.toml", size_px=384)
    frame = tmp_path / "f.png"
    assert main(["render", "--scene", str(scene), "--tip", "0", "0", "4", "--out", str(frame)]) == 0
    setup = read_setup(scene)
    with pytest.raises(SpotnavError, match="--fit-radius works with --method precise"):
        localize_batch([str(frame)], setup, "thesis", tmp_path / "p.csv", fit_radius=True)
    with pytest.raises(SpotnavError, match="at least 20 frames"):
        localize_batch([str(frame)], setup, "precise", tmp_path / "p.csv", fit_radius=True)
