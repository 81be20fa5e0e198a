"""The columns of the CSV files spotnav writes (the contract's first), and a header on its own.

Standard library only: the command line leaves a valid ``poses.csv`` (its header) when it is interrupted before
NumPy, Numba and the rest are imported.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence

__all__ = ["POSES_COLUMNS", "TRACK_COLUMNS", "TRUTH_COLUMNS", "write_header"]

POSES_COLUMNS = (
    *("image", "status", "x_mm", "y_mm", "z_mm", "dir_x", "dir_y", "dir_z"),  # the contract's
    *("spots", "sigma_mm", "rms_px", "fit_ratio", "other_dir_x", "other_dir_y", "other_dir_z", "time_ms", "detail"),
)

TRUTH_COLUMNS = ("frame", "image", "x_mm", "y_mm", "z_mm", "dir_x", "dir_y", "dir_z")
TRACK_COLUMNS = (
    *POSES_COLUMNS[:8],
    *("frame", "mode", "latency_ms", "decode_ms", *POSES_COLUMNS[8:15], "detail", "timestamp_s"),
)


def write_header(path: str | os.PathLike[str], columns: Sequence[str]) -> None:
    """Write a CSV file that holds only its header row (LF line ending), creating its folder."""
    folder = os.path.dirname(os.fspath(path))
    if folder:
        os.makedirs(folder, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as handle:
        csv.writer(handle, lineterminator="\n").writerow(columns)
