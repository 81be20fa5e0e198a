"""Reading and writing spotnav's files: setups, images, videos, truth, paths, known.csv and poses.csv.

Only this module, the experiments layer and the CLI touch the file system.
Every failure is a :class:`ValueError` subclass with a one-line message that
names the file.
"""

from __future__ import annotations

import contextlib
import csv
import glob
import json
import math
import mmap
import os
import select
import struct
import subprocess
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import PIL.Image

from spotnav.errors import InputError
from spotnav.pose.estimate import PoseEstimate
from spotnav.setup.config import Setup, SetupError, setup_from_toml
from spotnav.setup.geometry import InstrumentPose

__all__ = [
    "IMAGE_SUFFIXES",
    "POSES_COLUMNS",
    "TRACK_COLUMNS",
    "TRUTH_COLUMNS",
    "VIDEO_SUFFIXES",
    "CameraSettings",
    "Frame",
    "ImageReadError",
    "KnownPose",
    "PoseRow",
    "PosesWriter",
    "SequenceWriter",
    "display_name",
    "image_size",
    "is_live",
    "iter_frames",
    "pose_row",
    "read_image",
    "read_known_poses",
    "read_opencv_camera",
    "read_path_csv",
    "read_poses_csv",
    "read_setup",
    "setup_to_dict",
    "setup_to_toml",
    "track_row",
    "write_image",
    "write_truth_csv",
    "write_truth_json",
]

POSES_COLUMNS = (
    *("image", "status", "x_mm", "y_mm", "z_mm", "dir_x", "dir_y", "dir_z"),  # the contract's
    *("spots", "sigma_mm", "rms_px", "fit_ratio", "other_dir_x", "other_dir_y", "other_dir_z", "time_ms", "detail"),
)


class ImageReadError(InputError):
    """An image file is missing, empty, too large, not an image, or not the camera's size.

    ``status`` is the ``poses.csv`` status of its row: ``unreadable`` or ``wrong_size``.
    """

    def __init__(self, message: str, status: str = "unreadable") -> None:
        super().__init__(message)
        self.status = status


_DECODER_JOIN_S = 5.0  # how long a decoder told to stop may take to finish its frame
# A decoder process's record of a frame: its index (or _END, or _FAILED), the length of the note that follows (why
# a frame has no pixels, or the failure), decoding ms, Unix seconds when grabbed, perf_counter seconds when decoded.
_RECORD = struct.Struct("<qqddd")
_END, _FAILED = -1, -2
MAX_IMAGE_BYTES = 1 << 30  # the most memory one decoded image may take (8 bytes a pixel at most: RGBA, 16 bits)


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


def display_name(path: str | Path) -> str:
    """The path as text that can be written anywhere: bytes that are not UTF-8 become ``\\xNN`` escapes."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")


def _open_error(name: str, error: OSError) -> ImageReadError:
    if isinstance(error, FileNotFoundError):
        return ImageReadError(f"{name}: no such file")
    if isinstance(error, IsADirectoryError):
        return ImageReadError(f"{name}: is a folder, not an image")
    return ImageReadError(f"{name}: {error.strerror or error}")


def image_size(path: str | Path) -> tuple[int, int] | None:
    """Width and height in px from the file's header, without decoding it; None when Pillow does not read it.

    Raises
    ------
    ImageReadError
        If the file cannot be opened (missing, a directory, a symlink loop, no permission)
        or its header claims more pixels than Pillow's decompression-bomb limit.
    """
    name = display_name(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PIL.Image.DecompressionBombWarning)
            with PIL.Image.open(path) as image:
                return image.size
    except PIL.Image.DecompressionBombError:
        raise ImageReadError(f"{name}: its header claims over {2 * PIL.Image.MAX_IMAGE_PIXELS} pixels") from None
    except PIL.UnidentifiedImageError:
        return None
    except OSError as error:
        raise _open_error(name, error) from None
    except (ValueError, SyntaxError):  # a header Pillow cannot parse: let OpenCV decide
        return None


def _wrong_size(name: str, size: Sequence[int], expected: Sequence[int]) -> ImageReadError:
    message = f"{name}: image is {size[0]}x{size[1]} px, the setup's camera is {expected[0]}x{expected[1]} px"
    return ImageReadError(message, "wrong_size")


def read_image(
    path: str | Path, *, expected_size: tuple[int, int] | None = None, max_bytes: int = MAX_IMAGE_BYTES
) -> np.ndarray:
    """Read an 8- or 16-bit image as grey, RGB or RGBA (not OpenCV's BGR).

    The size in the file's header is checked before anything is decoded.

    Parameters
    ----------
    path : str or Path
    expected_size : (int, int), optional
        Width and height the image must have (the setup's camera), px.
    max_bytes : int
        The most memory the decoded image may take.

    Raises
    ------
    ImageReadError
        If the file is missing, a folder, empty, too large, not an image OpenCV can
        decode, or not ``expected_size`` (status ``wrong_size``).
    """
    name = display_name(path)
    size = image_size(path)
    if size is not None:
        if expected_size is not None and tuple(size) != tuple(expected_size):
            raise _wrong_size(name, size, expected_size)
        if 8 * size[0] * size[1] > max_bytes:
            raise ImageReadError(f"{name}: {size[0]}x{size[1]} px would take more than {max_bytes >> 20} MB")
    try:
        if Path(path).stat().st_size > max_bytes:
            raise ImageReadError(f"{name}: the file is larger than {max_bytes >> 20} MB")
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as error:
        raise _open_error(name, error) from None
    if data.size == 0:
        raise ImageReadError(f"{name}: the file is empty")
    try:
        image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    except cv2.error:
        image = None
    if image is None:
        raise ImageReadError(f"{name}: not an image OpenCV can read (or truncated, or too large)")
    if image.dtype not in (np.uint8, np.uint16):
        raise ImageReadError(f"{name}: {image.dtype} pixels, expected 8 or 16 bits")
    if expected_size is not None and image.shape[1::-1] != tuple(expected_size):
        raise _wrong_size(name, image.shape[1::-1], expected_size)
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
        raise InputError(f"{path}: cannot write the image")


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
    try:
        return int(row["frame"])
    except ValueError:
        raise InputError(f"{path}, line {number}: the frame must be a whole number") from None


def _read_truth_json(path: Path) -> KnownPose:
    """The one pose of the ``.json`` truth that ``render`` writes beside a frame."""
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
        tip = np.array(record["tip_mm"], dtype=float)
        axis = np.array(record["axis"], dtype=float)
        image = path.parent / record.get("image", path.with_suffix(".png").name)
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"{path}: cannot read the truth: {getattr(error, 'strerror', None) or error}") from None
    except (json.JSONDecodeError, KeyError, TypeError, ValueError):
        raise InputError(f"{path}: not a truth file of spotnav render (tip_mm, axis, image)") from None
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
        try:
            tip = np.array([float(row[k]) for k in ("x_mm", "y_mm", "z_mm")])
            axis = np.array([float(row[f"dir_{k}"]) for k in "xyz"]) if has_axis else None
        except (TypeError, ValueError):
            raise InputError(f"{path}, line {number}: the position must be numbers") from None
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
        try:
            sigma = float(row.get("sigma_mm") or "nan")
        except ValueError:
            raise InputError(f"{path}, line {number}: sigma_mm must be a number") from None
        if not any(values) and row["status"] != "ok":
            parsed.append(PoseRow(row["image"], row["status"], None, None, frame, sigma))
            continue
        try:
            numbers = np.array([float(v) for v in values])
        except (TypeError, ValueError):
            raise InputError(f"{path}, line {number}: the pose must be six numbers") from None
        if not np.all(np.isfinite(numbers)):
            raise InputError(f"{path}, line {number}: the pose must be finite")
        parsed.append(PoseRow(row["image"], row["status"], numbers[:3], numbers[3:], frame, sigma))
    return parsed


_OPENCV_MATRIX_KEYS = ("camera_matrix", "cameraMatrix", "K", "M", "intrinsic_matrix")
_OPENCV_DISTORTION_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "dist", "distortion")
_OPENCV_SIZE_KEYS = (("image_width", "imageWidth", "width"), ("image_height", "imageHeight", "height"))


def read_opencv_camera(path: str | Path) -> tuple[int, int, np.ndarray, np.ndarray]:
    """An OpenCV camera calibration: image size, camera matrix and distortion coefficients.

    Reads what ``cv2.FileStorage`` writes (YAML, XML or JSON), as OpenCV's
    calibration sample and tools do: ``camera_matrix`` and
    ``distortion_coefficients`` (or ``cameraMatrix``/``K``, ``dist_coeffs``/
    ``distCoeffs``/``D``) and ``image_width``, ``image_height``.

    Returns
    -------
    width_px, height_px : int
    matrix : ndarray, shape (3, 3)
    distortion : ndarray, shape (n,), n in (4, 5, 8, 12, 14)

    Raises
    ------
    InputError
        Naming the file and what is missing.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):  # OpenCV's parser raises its error through a SystemError
        raise InputError(f"{path}: not a file cv2.FileStorage reads (YAML, XML or JSON)") from None
    try:
        if not storage.isOpened():
            raise InputError(f"{path}: not a file cv2.FileStorage reads (YAML, XML or JSON)")

        def first(keys: Sequence[str]) -> cv2.FileNode | None:
            for key in keys:
                node = storage.getNode(key)
                if not node.empty():
                    return node
            return None

        matrix_node, distortion_node = first(_OPENCV_MATRIX_KEYS), first(_OPENCV_DISTORTION_KEYS)
        if matrix_node is None or distortion_node is None:
            missing = "camera_matrix" if matrix_node is None else "distortion_coefficients"
            raise InputError(f"{path}: no {missing} (OpenCV's calibration keys)")
        matrix, distortion = matrix_node.mat(), distortion_node.mat()
        sizes = [first(keys) for keys in _OPENCV_SIZE_KEYS]
        if any(node is None for node in sizes):
            raise InputError(f"{path}: no image_width and image_height")
        width, height = (int(node.real()) for node in sizes)  # type: ignore[union-attr]
    finally:
        storage.release()
    if matrix is None or matrix.shape != (3, 3):
        raise InputError(f"{path}: camera_matrix must be 3 x 3")
    if distortion is None:
        raise InputError(f"{path}: distortion_coefficients is not a matrix")
    return width, height, np.asarray(matrix, dtype=float), np.asarray(distortion, dtype=float).ravel()


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


# --- sequences: tracking input and output -------------------------------------------------------------------

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg")
VIDEO_SUFFIXES = (".mkv", ".avi", ".mp4", ".mov")
TRUTH_COLUMNS = ("frame", "image", "x_mm", "y_mm", "z_mm", "dir_x", "dir_y", "dir_z")
TRACK_COLUMNS = (
    *POSES_COLUMNS[:8],
    *("frame", "mode", "latency_ms", "decode_ms", *POSES_COLUMNS[8:15], "detail", "timestamp_s"),
)


def track_row(frame: Frame, estimate: PoseEstimate, mode: str, latency_ms: float) -> list[str]:
    """One ``poses.csv`` row of ``spotnav track``, in :data:`TRACK_COLUMNS` order."""
    row = dict(zip(POSES_COLUMNS, pose_row(frame.image, estimate), strict=True))
    row.update(frame=str(frame.index), mode=mode, latency_ms=f"{latency_ms:.2f}", decode_ms=f"{frame.decode_ms:.2f}")
    row["timestamp_s"] = f"{frame.timestamp_s:.6f}"
    return [row[column] for column in TRACK_COLUMNS]


@dataclass(frozen=True)
class Frame:
    """One decoded frame of a sequence.

    Attributes
    ----------
    index : int
        Position in the sequence, from 0.
    image : str
        The image file's path, or ``""`` for a video or camera frame.
    pixels : ndarray or None
        RGB (or grey) pixels; None when the file could not be read (see ``error``).
    decode_ms : float
        Time spent reading and decoding, ms.
    ready_s : float
        When the frame was decoded and asked for, the later of the two,
        :func:`time.perf_counter` seconds (one clock for every process on
        Linux): where its latency starts.
    error : str
        Why ``pixels`` is None.
    timestamp_s : float
        When the frame arrived, Unix seconds: when OpenCV grabbed a video's or
        a live source's frame (before decoding it; a camera's driver may have
        held it a few frames before), when a file was read.
    error_status : str
        The status of a frame without ``pixels``: ``unreadable`` or ``wrong_size``.
    """

    index: int
    image: str
    pixels: np.ndarray | None
    decode_ms: float
    ready_s: float
    error: str = ""
    timestamp_s: float = 0.0
    error_status: str = "unreadable"


@dataclass(frozen=True)
class CameraSettings:
    """What to ask a live camera for, through OpenCV's capture properties; None keeps the camera's own.

    Attributes
    ----------
    size_px : (int, int) or None
        Width and height, px (``CAP_PROP_FRAME_WIDTH``, ``CAP_PROP_FRAME_HEIGHT``).
    fps : float or None
        Frames per second (``CAP_PROP_FPS``).
    exposure : float or None
        ``CAP_PROP_EXPOSURE``, in the capture backend's own units.
    """

    size_px: tuple[int, int] | None = None
    fps: float | None = None
    exposure: float | None = None

    def requests(self) -> dict[int, float]:
        """OpenCV property -> value, for the settings that are given."""
        wanted: dict[int, float] = {}
        if self.size_px is not None:
            wanted[cv2.CAP_PROP_FRAME_WIDTH], wanted[cv2.CAP_PROP_FRAME_HEIGHT] = self.size_px
        if self.fps is not None:
            wanted[cv2.CAP_PROP_FPS] = self.fps
        if self.exposure is not None:
            wanted[cv2.CAP_PROP_EXPOSURE] = self.exposure
        return wanted


PROPERTY_NAMES = {
    cv2.CAP_PROP_FRAME_WIDTH: "width",
    cv2.CAP_PROP_FRAME_HEIGHT: "height",
    cv2.CAP_PROP_FPS: "fps",
    cv2.CAP_PROP_EXPOSURE: "exposure",
}


def _sequence_files(source: str) -> list[str] | None:
    """The image files a folder or glob names, sorted; None when ``source`` is neither."""
    path = Path(source)
    if path.is_dir():
        return sorted(str(p) for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if any(c in source for c in "*?["):
        return sorted(glob.glob(source))
    return None


def is_live(source: str) -> bool:
    """Whether ``source`` names a live camera or stream: a camera index, a URL or a GStreamer pipeline."""
    return source.isdigit() or "://" in source or " ! " in source


def iter_frames(
    source: str,
    *,
    ring: int = 0,
    camera: CameraSettings | None = None,
    report: Callable[[str], None] | None = None,
    expected_size: tuple[int, int] | None = None,
    while_waiting: Callable[[np.ndarray], object] | None = None,
) -> Iterator[Frame]:
    """Decode a sequence in order: a folder or glob of images, a video file, a camera, a URL or a pipeline.

    Parameters
    ----------
    source : str
        A folder or glob of images, a video file, a camera index (``0``), any
        URL that OpenCV's FFmpeg opens (``rtsp://...``), or a GStreamer
        pipeline (``... ! appsink``, with an OpenCV built with GStreamer).
    ring : int
        Decode video and camera frames into a ring of this many buffers, as a
        camera driver does: a frame's pixels are then overwritten ``ring``
        frames later (copy them to keep them). Fresh buffers for every frame
        (0, the default) cost a large allocation each, whose zeroing evicts
        the caches the localizer runs from.
    camera : CameraSettings, optional
        Settings to ask a live source for.
    report : callable, optional
        Receives one line with what a live source says it delivers.
    expected_size : (int, int), optional
        Width and height an image file must have: one that is not is not
        decoded (its frame's ``error_status`` is ``wrong_size``).
    while_waiting : callable, optional
        Decode a video file in a second process instead, one frame ahead, on
        other cores than the caller's thread, which is kept to the core it
        runs on while it iterates (threads it starts meanwhile stay there
        too; two trackers on one machine keep to two cores). While the
        next frame is not decoded yet, this is called with the last frame's
        pixels, again and again (:meth:`spotnav.app.track.Tracker.rehearse`
        keeps a tracked frame's code and data in that core's caches).
        ``ring`` must then be at least 1; frames are kept for ``ring`` frames
        as above. On Linux with two cores or more; elsewhere, and without
        room for the shared buffers, the video is decoded in the caller's
        thread, as are images and live sources.

    Raises
    ------
    ImageReadError
        If ``source`` names nothing that can be read (an unreadable image
        inside a folder yields a :class:`Frame` with its ``error`` instead),
        or a decoder process ends without the video's end.
    ValueError
        If ``camera`` settings are given for a source that is not live.
    """
    if ring < 0 or (while_waiting is not None and ring < 1):
        raise ValueError(f"ring must be at least {0 if while_waiting is None else 1}, got {ring}")
    wanted = camera.requests() if camera is not None else {}
    if wanted and not is_live(source):
        raise InputError(f"{source}: camera settings need a live camera, URL or pipeline, not files")
    files = _sequence_files(source)
    if files is not None:
        if not files:
            raise ImageReadError(f"{source}: no images ({', '.join(IMAGE_SUFFIXES)})")
        return _read_files(files, expected_size)
    capture = _open_capture(source, wanted)
    if is_live(source) and report is not None:
        delivered = ", ".join(f"{PROPERTY_NAMES[p]} {capture.get(p):g}" for p in PROPERTY_NAMES)
        report(f"{source}: the source reports {delivered}")
        for number, value in wanted.items():
            if abs(capture.get(number) - value) > 1e-6 * max(abs(value), 1.0):
                report(f"{source}: asked for {PROPERTY_NAMES[number]} {value:g}, it reports {capture.get(number):g}")
    if while_waiting is not None and not is_live(source):
        return _read_capture_in_process(source, capture, ring, while_waiting)
    return _read_capture(capture, ring)


def _read_files(files: Sequence[str], expected_size: tuple[int, int] | None) -> Iterator[Frame]:
    for index, name in enumerate(files):
        start = time.perf_counter()
        stamp = time.time()
        try:
            pixels, error, status = read_image(name, expected_size=expected_size), "", "unreadable"
        except ImageReadError as failure:
            pixels, error, status = None, str(failure), failure.status
        ready = time.perf_counter()
        yield Frame(index, display_name(name), pixels, 1000 * (ready - start), ready, error, stamp, status)


def _grabbed(capture: cv2.VideoCapture, reuse: bool) -> Iterator[tuple[np.ndarray, float, float]]:
    """``capture``'s frames as OpenCV decodes them (BGR; into one buffer with ``reuse``), each with the
    :func:`time.perf_counter` seconds when its decoding started and the Unix seconds when it was grabbed; the capture
    is released at the end."""
    decoded: np.ndarray | None = None
    try:
        while True:
            start = time.perf_counter()
            if not capture.grab():
                return
            stamp = time.time()
            ok, decoded = capture.retrieve(decoded if reuse else None)
            if not ok:
                return
            yield decoded, start, stamp
    finally:
        capture.release()


def _read_capture(capture: cv2.VideoCapture, ring: int) -> Iterator[Frame]:
    buffers: list[np.ndarray | None] = [None] * max(ring, 1)
    for index, (decoded, start, stamp) in enumerate(_grabbed(capture, bool(ring))):
        slot = index % len(buffers)
        pixels = cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB, dst=buffers[slot])
        if ring:
            buffers[slot] = pixels
        ready = time.perf_counter()
        yield Frame(index, "", pixels, 1000 * (ready - start), ready, timestamp_s=stamp)


def _split_cores() -> tuple[set[int], set[int]]:
    """One core for the caller's thread, the one it runs on (the scheduler's choice keeps two trackers on one
    machine apart), and the others for a decoder, of those this thread may run on; two empty sets with fewer than
    two (or where threads cannot be kept to cores)."""
    cores = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else set()
    if len(cores) < 2:
        return set(), set()
    own = {_current_core(cores)}
    return own, cores - own


def _current_core(cores: set[int]) -> int:
    """The core this thread last ran on (Linux's ``/proc``), if it is one of ``cores``; else the first of them."""
    try:
        stat = Path(f"/proc/self/task/{threading.get_native_id()}/stat").read_text()
        core = int(stat.rsplit(")", 1)[1].split()[36])  # field 39, "processor"; the fields after the name from 3
    except (OSError, ValueError, IndexError):
        return min(cores)
    return core if core in cores else min(cores)


def _read_capture_in_process(
    source: str, capture: cv2.VideoCapture, ring: int, while_waiting: Callable[[np.ndarray], object]
) -> Iterator[Frame]:
    """:func:`iter_frames`'s video frames from a decoder process, through a ring of ``ring + 1`` buffers in shared
    memory: a frame's buffer is written again once the frame ``ring`` later is handed over. In this thread, as
    :func:`_read_capture`, without a second core to decode on or shared memory to decode into."""
    own, others = _split_cores()
    shape = (ring + 1, int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)), int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), 3)
    buffers = _shared_buffers(math.prod(shape)) if own and min(shape) > 0 else None
    if buffers is None:
        return _read_capture(capture, ring)
    capture.release()
    return _frames_from_process(source, buffers, shape, (own, others), while_waiting)


def _shared_buffers(size: int) -> int | None:
    """A file descriptor of ``size`` bytes of anonymous shared memory, allocated (so that no write to it can fail
    later), which no file names (nothing is left behind however the process ends); None where there is none or
    no room."""
    if not hasattr(os, "memfd_create"):
        return None
    descriptor = os.memfd_create("spotnav-frames")
    try:
        os.posix_fallocate(descriptor, 0, size)
    except OSError:
        os.close(descriptor)
        return None
    return descriptor


def _frames_from_process(
    source: str,
    buffers: int,
    shape: tuple[int, int, int, int],
    cores: tuple[set[int], set[int]],
    while_waiting: Callable[[np.ndarray], object],
) -> Iterator[Frame]:
    """Start :func:`_decode_frames_main` in a new interpreter (not a fork: OpenCV's threads do not survive one) and
    hand over the frames it decodes into ``buffers`` (a file descriptor), this thread on the first of ``cores``
    (own, the decoder's) meanwhile.

    The decoder decodes a frame once the one before was handed over (a byte on its standard input each) and sends
    a :data:`_RECORD` for each, then :data:`_END` (or :data:`_FAILED`), each followed by its note if any. It runs in
    its own session: a signal to this process group is this process's to act on.
    """
    own, others = cores
    # Mapped in full now (Linux's MAP_POPULATE), not page by page as the first frames are read: that cost the first
    # frame, an acquisition, 190 page faults and 2-4 ms.
    populate = mmap.MAP_SHARED | getattr(mmap, "MAP_POPULATE", 0)
    ring = np.frombuffer(mmap.mmap(buffers, math.prod(shape), flags=populate), dtype=np.uint8).reshape(shape)
    records, records_out = os.pipe()
    arguments = [source, str(buffers), ",".join(map(str, shape)), str(records_out), ",".join(map(str, others))]
    package_root = str(Path(__file__).resolve().parents[2])
    paths = [package_root, *filter(None, [os.environ.get("PYTHONPATH")])]
    decoder = subprocess.Popen(
        [sys.executable, "-P", "-c", "import spotnav.files as f; f._decode_frames_main()", *arguments],
        stdin=subprocess.PIPE,
        pass_fds=(buffers, records_out),
        env={**os.environ, "PYTHONPATH": os.pathsep.join(paths)},
        start_new_session=True,
    )
    os.close(records_out)
    os.close(buffers)
    arrived = select.poll()
    arrived.register(records, select.POLLIN)
    affinity = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, own)
        last: np.ndarray | None = None
        while True:
            asked = time.perf_counter()
            while last is not None and not arrived.poll(0):
                while_waiting(last)
            record = _read_exactly(records, _RECORD.size)
            if len(record) < _RECORD.size:
                code = decoder.wait(_DECODER_JOIN_S)
                raise ImageReadError(f"{source}: the decoder process ended before the video did (exit code {code})")
            index, note_length, decode_ms, stamp, decoded = _RECORD.unpack(record)
            note = _read_exactly(records, note_length).decode(errors="replace")
            if index == _END:
                return
            if index == _FAILED:
                raise ImageReadError(note)
            pixels = None if note else ring[index % len(ring)]
            with contextlib.suppress(BrokenPipeError):  # a decoder that died: the next read says so
                os.write(decoder.stdin.fileno(), b"\0")  # the decoder may go on with the next frame
            last = last if pixels is None else pixels
            ready = max(decoded, asked)
            yield Frame(index, "", pixels, decode_ms, ready, note, stamp, "wrong_size" if note else "unreadable")
    finally:
        try:
            os.sched_setaffinity(0, affinity)
        finally:
            os.close(records)
            decoder.stdin.close()
            try:
                decoder.wait(_DECODER_JOIN_S)
            except subprocess.TimeoutExpired:
                decoder.kill()
                decoder.wait()


def _read_exactly(descriptor: int, size: int) -> bytes:
    """``size`` bytes from a pipe, or fewer if it ends first."""
    data = b""
    while len(data) < size:
        more = os.read(descriptor, size - len(data))
        if not more:
            break
        data += more
    return data


def _send_record(
    descriptor: int, index: int, note: str = "", times: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> None:
    """One :data:`_RECORD` and its note."""
    encoded = note.encode()
    os.write(descriptor, _RECORD.pack(index, len(encoded), *times) + encoded)


def _decode_frames_main() -> None:
    """A decoder process's work (started by :func:`_frames_from_process`; its arguments: the source, the buffers'
    file descriptor, their shape, the records' file descriptor and the cores to run on, comma-separated).

    Frame ``k`` is decoded into buffer ``k % len(buffers)``, the first at once and each next one when a byte on
    standard input says that the one before was handed over; a frame of another size is not (its record's note
    says why). The process ends at the video's end or when its standard input does (the parent stopped, or is
    gone); a failure is sent as :data:`_FAILED` with its message.
    """
    source, buffers, shape_text, descriptor, cores = sys.argv[1:]
    records = int(descriptor)
    try:
        if cores:
            os.sched_setaffinity(0, {int(core) for core in cores.split(",")})
        shape = tuple(int(n) for n in shape_text.split(","))
        ring = np.frombuffer(mmap.mmap(int(buffers), math.prod(shape)), dtype=np.uint8).reshape(shape)
        _decode_into(_open_capture(source, {}), ring, records)
    except BrokenPipeError:  # the parent stopped reading
        return
    except Exception as error:  # any failure is the parent's to report, in one line
        with contextlib.suppress(BrokenPipeError):
            _send_record(records, _FAILED, f"{source}: the decoder process failed: {error}")


def _decode_into(capture: cv2.VideoCapture, ring: np.ndarray, records: int) -> None:
    """:func:`_decode_frames_main`'s loop: ``capture``'s frames into the buffers ``ring`` (B, H, W, 3), each next
    one once a byte on standard input says so."""
    frames = _grabbed(capture, reuse=True)
    with contextlib.closing(frames):
        for index, (decoded, start, stamp) in enumerate(frames):
            times = (1000 * (time.perf_counter() - start), stamp)
            note = ""
            if decoded.shape != ring.shape[1:] or decoded.dtype != np.uint8:
                size, first = f"{decoded.shape[1]}x{decoded.shape[0]}", f"{ring.shape[2]}x{ring.shape[1]}"
                note = f"frame {index} is {size} px {decoded.dtype}, the video's first {first} px uint8"
            else:
                cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB, dst=ring[index % len(ring)])
            _send_record(records, index, note, (*times, time.perf_counter()))
            if not os.read(0, 1):  # the frame was handed over: decode the next one (or the parent stopped)
                return
        _send_record(records, _END)


def _open_capture(source: str, wanted: Mapping[int, float]) -> cv2.VideoCapture:
    """An opened capture of a video file, camera index, URL or GStreamer pipeline, with ``wanted`` properties."""
    # One decoding thread: threads that decode ahead would compete with the localizer for the cores.
    params = [cv2.CAP_PROP_N_THREADS, 1]
    if source.isdigit():  # a camera backend (V4L2) may refuse open parameters: none
        capture = cv2.VideoCapture(int(source), cv2.CAP_ANY)
    elif " ! " in source:
        if "GStreamer:                   YES" not in cv2.getBuildInformation():
            raise ImageReadError(f"{source}: this OpenCV has no GStreamer (cv2.getBuildInformation())")
        capture = cv2.VideoCapture(source, cv2.CAP_GSTREAMER)
    elif "://" in source:
        capture = cv2.VideoCapture(source, cv2.CAP_FFMPEG, params)
    elif Path(source).is_file() and Path(source).suffix.lower() in VIDEO_SUFFIXES:
        capture = cv2.VideoCapture(source, cv2.CAP_FFMPEG, params)
    elif Path(source).is_file():
        raise ImageReadError(f"{source}: not a video ({', '.join(VIDEO_SUFFIXES)}), folder or glob of images")
    elif Path(source).exists():
        raise ImageReadError(f"{source}: not a file, folder or glob of images")
    else:
        raise ImageReadError(f"{source}: no such file, folder, camera or URL")
    if not capture.isOpened():
        raise ImageReadError(f"{source}: cannot open the video, camera, URL or pipeline")
    for number, value in wanted.items():
        capture.set(number, value)
    return capture


class SequenceWriter:
    """Write frames as numbered PNGs in a folder, or as a lossless FFV1 video (``.mkv``).

    Parameters
    ----------
    out : str or Path
        A folder, or a file with a suffix in :data:`VIDEO_SUFFIXES` (FFV1 in Matroska: use ``.mkv``).
    fps : float
        The video's frame rate.
    """

    def __init__(self, out: str | Path, fps: float) -> None:
        self.out = Path(out)
        self.fps = fps
        self.video = self.out.suffix.lower() in VIDEO_SUFFIXES
        if self.video and self.out.suffix.lower() != ".mkv":
            raise InputError(f"{self.out}: lossless video is written as FFV1 in Matroska: use .mkv")
        self._writer: cv2.VideoWriter | None = None
        (self.out.parent if self.video else self.out).mkdir(parents=True, exist_ok=True)

    def write(self, index: int, rgb: np.ndarray) -> str:
        """Write one frame; returns the PNG's file name (``""`` for a video)."""
        if not self.video:
            name = f"frame_{index:05d}.png"
            write_image(self.out / name, rgb)
            return name
        if self._writer is None:
            height, width = rgb.shape[:2]
            fourcc = cv2.VideoWriter.fourcc(*"FFV1")
            self._writer = cv2.VideoWriter(str(self.out), fourcc, self.fps, (width, height))
            if not self._writer.isOpened():
                raise InputError(f"{self.out}: cannot write an FFV1 video")
        self._writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        return ""

    def close(self) -> None:
        """Finish the video."""
        if self._writer is not None:
            self._writer.release()

    def __enter__(self) -> SequenceWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_truth_csv(path: str | Path, rows: Iterable[tuple[int, str, InstrumentPose]]) -> None:
    """Write ``truth.csv`` (:data:`TRUTH_COLUMNS`): frame, image file name and the true pose."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(TRUTH_COLUMNS)
        for frame, image, pose in rows:
            writer.writerow([frame, image, *(_format(v) for v in (*pose.tip_in_eye, *pose.axis))])


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
                try:
                    tip = [float(row[c]) for c in ("x_mm", "y_mm", "z_mm")]
                except (TypeError, ValueError):
                    raise InputError(f"{path}: row {line}: x_mm, y_mm, z_mm must be numbers") from None
                if not np.all(np.isfinite(tip)):
                    raise InputError(f"{path}: row {line}: x_mm, y_mm, z_mm must be finite")
                tips.append(tip)
    except (UnicodeDecodeError, csv.Error) as error:
        raise InputError(f"{path}: not a UTF-8 CSV file ({error})") from None
    if len(tips) < 2:
        raise InputError(f"{path}: a path needs at least two rows")
    return np.array(tips)
