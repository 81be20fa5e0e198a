"""Pose tables: ``poses.csv`` written row by row, and the truth and known poses read and written.

:class:`PosesWriter` writes a localization's or a track's ``poses.csv`` (:data:`POSES_COLUMNS`,
:data:`TRACK_COLUMNS`; :func:`pose_row`, :func:`track_row`), each row on disk at once. The truth of rendered frames
is written as ``truth.csv`` or a ``.json`` beside a frame, and read back, with ``known.csv``, as :class:`KnownPose`;
:func:`read_poses_csv` reads a ``poses.csv`` back and :func:`read_path_csv` a path of tips. A field is checked to be
a number before it is converted; every failure is an :class:`~spotnav.errors.InputError` naming the file and line.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spotnav.errors import InputError
from spotnav.files.capture import Frame
from spotnav.files.columns import POSES_COLUMNS, TRACK_COLUMNS, TRUTH_COLUMNS
from spotnav.files.numbers import json_floats, parse_float, parse_int
from spotnav.files.setup_files import setup_to_dict
from spotnav.pose.estimate import PoseEstimate
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose

__all__ = [
    "POSES_COLUMNS",
    "TRACK_COLUMNS",
    "TRUTH_COLUMNS",
    "KnownPose",
    "PoseRow",
    "PosesWriter",
    "pose_row",
    "read_known_poses",
    "read_path_csv",
    "read_poses_csv",
    "track_row",
    "write_truth_csv",
    "write_truth_json",
]


def _format(value: float) -> str:
    return f"{value:.6f}"


def pose_row(image: str, estimate: PoseEstimate, time_ms: float | None = None) -> list[str]:
    """One ``poses.csv`` row, in :data:`POSES_COLUMNS` order."""
    if estimate.ok:
        numbers = [_format(v) for v in np.concatenate(estimate.pose())]
    else:
        numbers = [""] * 6
    measured = (estimate.sigma_mm, estimate.rms_px, estimate.fit_ratio)
    quality = ["" if not np.isfinite(v) else _format(v) for v in measured]
    other = [""] * 3 if estimate.other_axis is None else [_format(v) for v in estimate.other_axis]
    timing = "" if time_ms is None else f"{time_ms:.1f}"
    return [image, estimate.status, *numbers, str(estimate.spots), *quality, *other, timing, estimate.detail]


class PosesWriter:
    """``poses.csv`` written row by row, each row on disk as soon as it is written.

    A run that stops early (Ctrl-C, SIGTERM, a crash) leaves every finished row.
    Lines end in LF. Use it as a context manager. The contract's columns come
    first; ``sigma_mm`` is the precise method's 1-sigma tip uncertainty,
    ``rms_px`` its edge points' RMS distance from the fitted cones,
    ``fit_ratio`` that RMS over the one the points' noise explains,
    ``other_dir_*`` its cross-check axis (fitted without the insertion point,
    or with it for ``precise-free``); all empty for the thesis's method.

    Parameters
    ----------
    path : str or Path
    columns : sequence of str
        The header: the contract's columns first (:data:`POSES_COLUMNS` or :data:`TRACK_COLUMNS`).
    """

    def __init__(self, path: str | Path, columns: Sequence[str] = POSES_COLUMNS) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._handle = self.path.open("w", newline="", encoding="utf-8")
        self._writer = csv.writer(self._handle, lineterminator="\n")
        self.rows = 0
        self.write(columns)
        self.rows = 0

    def write(self, row: Sequence[str]) -> None:
        """Write one row and flush it to the file."""
        self._writer.writerow(row)
        self._handle.flush()
        self.rows += 1

    def close(self) -> None:
        """Close the file."""
        self._handle.close()

    def __enter__(self) -> PosesWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def track_row(frame: Frame, estimate: PoseEstimate, mode: str, latency_ms: float) -> list[str]:
    """One ``poses.csv`` row of ``spotnav track``, in :data:`TRACK_COLUMNS` order."""
    row = dict(zip(POSES_COLUMNS, pose_row(frame.image, estimate), strict=True))
    row.update(frame=str(frame.index), mode=mode, latency_ms=f"{latency_ms:.2f}", decode_ms=f"{frame.decode_ms:.2f}")
    row["timestamp_s"] = f"{frame.timestamp_s:.6f}"
    return [row[column] for column in TRACK_COLUMNS]


def write_truth_json(
    path: str | Path, pose: InstrumentPose, beam_axes: np.ndarray, setup: Setup, **extra: object
) -> None:
    """Write the truth beside a rendered frame."""
    record = {
        "tip_mm": pose.tip_in_eye.tolist(),
        "axis": pose.axis.tolist(),
        "beam_axes": np.asarray(beam_axes).tolist(),
        **extra,
        "setup": setup_to_dict(setup),
    }
    Path(path).write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")


def write_truth_csv(path: str | Path, rows: Iterable[tuple[int, str, InstrumentPose]]) -> None:
    """Write ``truth.csv`` (:data:`TRUTH_COLUMNS`): frame, image file name and the true pose."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(TRUTH_COLUMNS)
        for frame, image, pose in rows:
            writer.writerow([frame, image, *(_format(v) for v in (*pose.tip_in_eye, *pose.axis))])


def _read_csv_rows(path: Path, needed: Sequence[str]) -> list[dict[str, str]]:
    """A CSV file's rows as dicts; InputError naming the file when it cannot be read or lacks a column."""
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
    except OSError as error:
        raise InputError(f"{path}: cannot read: {error.strerror}") from None
    except (UnicodeDecodeError, csv.Error) as error:
        raise InputError(f"{path}: not a UTF-8 CSV file ({error})") from None
    if not rows or any(name not in rows[0] for name in needed):
        raise InputError(f"{path}: needs a header with the columns {', '.join(needed)} and at least one row")
    return rows


@dataclass(frozen=True)
class KnownPose:
    """One row of ``known.csv``: an image at a known tip position (and, optionally, axis)."""

    image: Path
    tip_in_eye: np.ndarray
    axis: np.ndarray | None
    frame: int | None = None


def _frame_number(row: dict[str, str], path: Path, number: int) -> int | None:
    """The optional ``frame`` column (a video's frame index), or None where it is absent or empty."""
    if not row.get("frame"):
        return None
    frame = parse_int(row["frame"])
    if frame is None:
        raise InputError(f"{path}, line {number}: the frame must be a whole number")
    return frame


def _floats(row: Mapping[str, str | None], keys: Iterable[str]) -> np.ndarray | None:
    """The row's fields ``keys`` as numbers, or None where one is missing or not a number."""
    numbers = [parse_float(row[key]) for key in keys]
    return None if None in numbers else np.array(numbers)


def _read_truth_json(path: Path) -> KnownPose:
    """The one pose of the ``.json`` truth that ``render`` writes beside a frame."""
    refused = f"{path}: not a truth file of spotnav render (tip_mm, axis, image)"
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
        tip = json_floats(record["tip_mm"])
        axis = json_floats(record["axis"]) if tip is not None else None
        image = path.parent / record.get("image", path.with_suffix(".png").name)
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"{path}: cannot read the truth: {getattr(error, 'strerror', None) or error}") from None
    except (json.JSONDecodeError, KeyError, TypeError):
        raise InputError(refused) from None
    if tip is None or axis is None:
        raise InputError(refused)
    if tip.shape != (3,) or axis.shape != (3,) or not (np.all(np.isfinite(tip)) and np.all(np.isfinite(axis))):
        raise InputError(f"{path}: tip_mm and axis must be three finite numbers each")
    return KnownPose(image, tip, axis, None)


def read_known_poses(path: str | Path) -> list[KnownPose]:
    """Read ``known.csv`` (contract: ``image,x_mm,y_mm,z_mm``; optional ``dir_x,dir_y,dir_z``).

    Image paths are taken relative to the CSV's folder unless absolute; an
    empty one (a video's frame, as in ``truth.csv``) stays empty, with the
    optional ``frame`` column's index. A ``.json`` file is the single frame's
    truth that ``spotnav render`` writes beside it.

    Raises
    ------
    InputError
        Naming the file and the row for a missing column or a bad number.
    """
    path = Path(path)
    if path.suffix.lower() == ".json":
        return [_read_truth_json(path)]
    rows = _read_csv_rows(path, ("image", "x_mm", "y_mm", "z_mm"))
    has_axis = all(f"dir_{k}" in rows[0] for k in "xyz")
    poses = []
    for number, row in enumerate(rows, start=2):
        tip = _floats(row, ("x_mm", "y_mm", "z_mm"))
        axis = _floats(row, [f"dir_{k}" for k in "xyz"]) if has_axis and tip is not None else None
        if tip is None or (has_axis and axis is None):
            raise InputError(f"{path}, line {number}: the position must be numbers")
        if not np.all(np.isfinite(tip)) or (axis is not None and not np.all(np.isfinite(axis))):
            raise InputError(f"{path}, line {number}: the position must be finite")
        image = Path(row["image"])
        if row["image"] and not image.is_absolute():
            image = path.parent / image
        poses.append(KnownPose(image, tip, axis, _frame_number(row, path, number)))
    return poses


@dataclass(frozen=True)
class PoseRow:
    """One row of a ``poses.csv``: the contract's columns, parsed.

    ``tip_in_eye`` and ``axis`` are None when the row has no pose; ``sigma_mm``
    is NaN where the file has no such column or value.
    """

    image: str
    status: str
    tip_in_eye: np.ndarray | None
    axis: np.ndarray | None
    frame: int | None = None
    sigma_mm: float = float("nan")


def read_poses_csv(path: str | Path) -> list[PoseRow]:
    """Read a ``poses.csv``: the contract's columns, and ``frame`` and ``sigma_mm`` where the file has them.

    Raises
    ------
    InputError
        Naming the file and the line for a missing column, a bad number or an ``ok`` row without a pose.
    """
    path = Path(path)
    needed = POSES_COLUMNS[:8]
    rows = _read_csv_rows(path, needed)
    parsed = []
    for number, row in enumerate(rows, start=2):
        values = [row[k] for k in needed[2:]]
        frame = _frame_number(row, path, number)
        sigma = parse_float(row.get("sigma_mm") or "nan")
        if sigma is None:
            raise InputError(f"{path}, line {number}: sigma_mm must be a number")
        if not any(values) and row["status"] != "ok":
            parsed.append(PoseRow(row["image"], row["status"], None, None, frame, sigma))
            continue
        numbers = _floats(row, needed[2:])
        if numbers is None:
            raise InputError(f"{path}, line {number}: the pose must be six numbers")
        if not np.all(np.isfinite(numbers)):
            raise InputError(f"{path}, line {number}: the pose must be finite")
        parsed.append(PoseRow(row["image"], row["status"], numbers[:3], numbers[3:], frame, sigma))
    return parsed


def read_path_csv(path: str | Path) -> np.ndarray:
    """Read a path's tips (columns ``x_mm,y_mm,z_mm``, more allowed), shape (N, 3), N >= 2.

    Raises
    ------
    InputError
        Naming the file, the row or the missing column.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            reader = csv.DictReader(handle)
            missing = [c for c in ("x_mm", "y_mm", "z_mm") if c not in (reader.fieldnames or [])]
            if missing:
                raise InputError(f"{path}: missing column(s) {', '.join(missing)}")
            tips = []
            for line, row in enumerate(reader, start=2):
                tip = _floats(row, ("x_mm", "y_mm", "z_mm"))
                if tip is None:
                    raise InputError(f"{path}: row {line}: x_mm, y_mm, z_mm must be numbers")
                if not np.all(np.isfinite(tip)):
                    raise InputError(f"{path}: row {line}: x_mm, y_mm, z_mm must be finite")
                tips.append(tip)
    except (UnicodeDecodeError, csv.Error) as error:
        raise InputError(f"{path}: not a UTF-8 CSV file ({error})") from None
    if len(tips) < 2:
        raise InputError(f"{path}: a path needs at least two rows")
    return np.array(tips)
