"""Reading and writing spotnav's files: setups, images, truth, known.csv and poses.csv.

Only this module, the experiments layer and the CLI touch the file system.
Every failure is a :class:`ValueError` subclass with a one-line message that
names the file.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from spotnav.config import Setup, SetupError, setup_from_toml
from spotnav.geometry import InstrumentPose
from spotnav.localize import PoseEstimate

__all__ = [
    "POSES_COLUMNS",
    "ImageReadError",
    "KnownPose",
    "pose_row",
    "read_image",
    "read_known_poses",
    "read_setup",
    "setup_to_dict",
    "setup_to_toml",
    "write_image",
    "write_poses_csv",
    "write_truth_json",
]

POSES_COLUMNS = (
    *("image", "status", "x_mm", "y_mm", "z_mm", "dir_x", "dir_y", "dir_z"),  # the contract's
    *("spots", "sigma_mm", "rms_px", "other_dir_x", "other_dir_y", "other_dir_z", "time_ms", "detail"),
)


class ImageReadError(ValueError):
    """An image file is missing, empty or not an image."""


def read_setup(path: str | Path) -> Setup:
    """Read and validate a TOML setup file.

    Raises
    ------
    SetupError
        Naming the file, and the key for invalid values.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise SetupError(f"{path}: cannot read the setup: {getattr(error, 'strerror', None) or error}") from None
    try:
        return setup_from_toml(text)
    except SetupError as error:
        raise SetupError(f"{path}: {error}") from None


def read_image(path: str | Path) -> np.ndarray:
    """Read an 8- or 16-bit image as grey, RGB or RGBA (not OpenCV's BGR).

    Raises
    ------
    ImageReadError
        If the file is missing, empty or not an image OpenCV can decode.
    """
    path = Path(path)
    if not path.is_file():
        raise ImageReadError(f"{path}: no such file")
    data = np.fromfile(path, dtype=np.uint8)
    if data.size == 0:
        raise ImageReadError(f"{path}: the file is empty")
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ImageReadError(f"{path}: not an image OpenCV can read (or truncated)")
    if image.dtype not in (np.uint8, np.uint16):
        raise ImageReadError(f"{path}: {image.dtype} pixels, expected 8 or 16 bits")
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA)
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0]
    return image


def write_image(path: str | Path, rgb: np.ndarray) -> None:
    """Write an RGB (or grey) image; the format follows the suffix."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    image = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR) if rgb.ndim == 3 else rgb
    if not cv2.imwrite(str(path), image):
        raise ValueError(f"{path}: cannot write the image")


def setup_to_dict(setup: Setup) -> dict:
    """The setup as plain data (for JSON)."""
    return asdict(setup)


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


def _format(value: float) -> str:
    return f"{value:.6f}"


def pose_row(image: str, estimate: PoseEstimate, time_ms: float | None = None) -> list[str]:
    """One ``poses.csv`` row, in :data:`POSES_COLUMNS` order."""
    if estimate.ok:
        assert estimate.tip_in_eye is not None and estimate.axis is not None
        numbers = [_format(v) for v in (*estimate.tip_in_eye, *estimate.axis)]
    else:
        numbers = [""] * 6
    quality = ["" if not np.isfinite(v) else _format(v) for v in (estimate.sigma_mm, estimate.rms_px)]
    other = [""] * 3 if estimate.other_axis is None else [_format(v) for v in estimate.other_axis]
    timing = "" if time_ms is None else f"{time_ms:.1f}"
    return [image, estimate.status, *numbers, str(estimate.spots), *quality, *other, timing, estimate.detail]


def write_poses_csv(path: str | Path, rows: Iterable[Sequence[str]]) -> None:
    """Write ``poses.csv``: the contract's columns first, then :data:`POSES_COLUMNS`' own.

    ``sigma_mm`` is the precise method's 1-sigma tip uncertainty, ``rms_px`` its
    edge points' RMS distance from the fitted cones, ``other_dir_*`` its
    cross-check axis (fitted without the insertion point, or with it for
    ``precise-free``); all empty for the thesis's method.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(POSES_COLUMNS)
        writer.writerows(rows)


@dataclass(frozen=True)
class KnownPose:
    """One row of ``known.csv``: an image at a known tip position (and, optionally, axis)."""

    image: Path
    tip_in_eye: np.ndarray
    axis: np.ndarray | None


def read_known_poses(path: str | Path) -> list[KnownPose]:
    """Read ``known.csv`` (contract: ``image,x_mm,y_mm,z_mm``; optional ``dir_x,dir_y,dir_z``).

    Image paths are taken relative to the CSV's folder unless absolute.

    Raises
    ------
    ValueError
        Naming the file and the row for a missing column or a bad number.
    """
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
    except OSError as error:
        raise ValueError(f"{path}: cannot read: {error.strerror}") from None
    needed = ["image", "x_mm", "y_mm", "z_mm"]
    if not rows or any(name not in rows[0] for name in needed):
        raise ValueError(f"{path}: needs a header with the columns {', '.join(needed)} and at least one row")
    has_axis = all(f"dir_{k}" in rows[0] for k in "xyz")
    poses = []
    for number, row in enumerate(rows, start=2):
        try:
            tip = np.array([float(row[k]) for k in ("x_mm", "y_mm", "z_mm")])
            axis = np.array([float(row[f"dir_{k}"]) for k in "xyz"]) if has_axis else None
        except (TypeError, ValueError):
            raise ValueError(f"{path}, line {number}: the position must be numbers") from None
        if not np.all(np.isfinite(tip)) or (axis is not None and not np.all(np.isfinite(axis))):
            raise ValueError(f"{path}, line {number}: the position must be finite")
        image = Path(row["image"])
        poses.append(KnownPose(image if image.is_absolute() else path.parent / image, tip, axis))
    return poses


def setup_to_toml(setup: Setup, header: str = "") -> str:
    """The setup as a TOML file that :func:`read_setup` reads back to the same setup.

    Parameters
    ----------
    setup : Setup
    header : str
        Comment lines to put first (without ``#``).
    """
    lines = [f"# {line}" for line in header.splitlines()]
    for section, values in asdict(setup).items():
        lines += ["", f"[{section}]"]
        for key, value in values.items():
            if value is None:
                continue
            lines.append(f"{key} = {_toml_value(value)}")
    return "\n".join(lines).lstrip("\n") + "\n"


def _toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} as TOML")
