from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from spotnav.errors import InputError, SpotnavError
from spotnav.files.poses import POSES_COLUMNS, PosesWriter, pose_row, read_known_poses, read_path_csv, read_poses_csv
from spotnav.pose.estimate import PoseEstimate


def test_poses_rows_are_on_disk_as_soon_as_they_are_written(tmp_path: Path) -> None:
    path = tmp_path / "poses.csv"
    with PosesWriter(path) as writer:
        writer.write(pose_row("a.png", PoseEstimate("no_spot", detail="none")))
        assert path.read_bytes().count(b"\n") == 2 and b"\r" not in path.read_bytes()
        assert writer.rows == 1


def test_poses_csv_has_the_contract_columns_first(tmp_path: Path) -> None:
    ok = PoseEstimate("ok", tip_in_eye=np.array([1.0, 2.0, 3.0]), axis=np.array([0.0, 0.0, -1.0]), spots=1)
    rows = [pose_row("a.png", ok, 12.0), pose_row("b.png", PoseEstimate("no_spot", detail="dark"))]
    with PosesWriter(tmp_path / "poses.csv") as writer:
        for row in rows:
            writer.write(row)
    with (tmp_path / "poses.csv").open() as handle:
        table = list(csv.DictReader(handle))
    assert list(table[0])[:8] == ["image", "status", "x_mm", "y_mm", "z_mm", "dir_x", "dir_y", "dir_z"]
    assert tuple(table[0]) == POSES_COLUMNS
    assert float(table[0]["z_mm"]) == 3.0 and table[0]["status"] == "ok"
    assert table[1]["x_mm"] == "" and table[1]["detail"] == "dark"


def test_read_known_poses(tmp_path: Path) -> None:
    (tmp_path / "known.csv").write_text(
        "image,x_mm,y_mm,z_mm,dir_x,dir_y,dir_z\na.png,1,2,4,0,0,-1\n/abs/b.png,0,0,5,0,0,-1\n"
    )
    first, second = read_known_poses(tmp_path / "known.csv")
    assert first.image == tmp_path / "a.png" and second.image == Path("/abs/b.png")
    np.testing.assert_array_equal(first.tip_in_eye, [1, 2, 4])
    np.testing.assert_array_equal(second.axis, [0, 0, -1])
    (tmp_path / "bad.csv").write_text("image,x_mm,y_mm,z_mm\na.png,1,two,4\n")
    with pytest.raises(SpotnavError, match="line 2"):
        read_known_poses(tmp_path / "bad.csv")
    with pytest.raises(SpotnavError, match="cannot read"):
        read_known_poses(tmp_path / "missing.csv")


def test_a_field_that_is_not_a_number_is_refused_naming_the_line(tmp_path: Path) -> None:
    cases = [
        ("known.csv", "image,x_mm,y_mm,z_mm,frame\na.png,1,2,4,1.5\n", read_known_poses, "line 2: the frame must be"),
        ("known.csv", "image,x_mm,y_mm,z_mm,dir_x,dir_y,dir_z\na.png,1,2,4,0,0\n", read_known_poses, "line 2: the pos"),
        ("poses.csv", f"{','.join(POSES_COLUMNS)}\na.png,ok,1,2,3,0,0,-1,1,wide\n", read_poses_csv, "line 2: sigma_mm"),
        (
            "poses.csv",
            f"{','.join(POSES_COLUMNS[:8])}\na.png,ok,1,2,x,0,0,-1\n",
            read_poses_csv,
            "line 2: the pose must",
        ),
        ("path.csv", "x_mm,y_mm,z_mm\n1,2,3\n1,2\n", read_path_csv, "row 3: x_mm, y_mm, z_mm must be numbers"),
        ("truth.json", '{"tip_mm": ["one", 2, 3], "axis": [0, 0, -1]}', read_known_poses, "not a truth file"),
        ("truth.json", '{"tip_mm": [1, 2], "axis": [0, 0, -1]}', read_known_poses, "three finite numbers each"),
    ]
    for name, text, read, message in cases:
        (tmp_path / name).write_text(text)
        with pytest.raises(InputError, match=message):
            read(tmp_path / name)
    (tmp_path / "truth.json").write_text('{"tip_mm": [" 1", "2_0", 3], "axis": [0, 0, -1], "image": "a.png"}')
    (pose,) = read_known_poses(tmp_path / "truth.json")  # numbers' text is read as NumPy reads it
    np.testing.assert_array_equal(pose.tip_in_eye, [1.0, 20.0, 3.0])
    assert pose.image == tmp_path / "a.png"
