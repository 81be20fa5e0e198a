from __future__ import annotations

import csv
from pathlib import Path

from spotnav.files.columns import POSES_COLUMNS, TRACK_COLUMNS, write_header
from spotnav.files.poses import PosesWriter


def test_a_header_alone_is_what_the_writer_starts_with(tmp_path: Path) -> None:
    for columns in (POSES_COLUMNS, TRACK_COLUMNS):
        alone, written = tmp_path / "deeper" / "alone.csv", tmp_path / "written.csv"
        write_header(alone, columns)
        with PosesWriter(written, columns):
            pass
        assert alone.read_bytes() == written.read_bytes() == (",".join(columns) + "\n").encode()
        assert list(csv.reader(alone.open())) == [list(columns)]


def test_the_contract_columns_come_first() -> None:
    contract = ("image", "status", "x_mm", "y_mm", "z_mm", "dir_x", "dir_y", "dir_z")
    assert POSES_COLUMNS[:8] == TRACK_COLUMNS[:8] == contract
    assert TRACK_COLUMNS[-1] == "timestamp_s" and len(set(TRACK_COLUMNS)) == len(TRACK_COLUMNS)
