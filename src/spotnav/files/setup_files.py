"""Setup files: a setup's TOML read and written, and a camera calibration as OpenCV's tools write it.

:func:`read_setup` reads and validates a TOML setup (its errors name the file and the key), :func:`setup_to_toml`
writes one that reads back to the same setup, and :func:`read_opencv_camera` reads the image size, camera matrix and
distortion coefficients from a ``cv2.FileStorage`` file (YAML, XML or JSON).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, fields
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from spotnav.errors import InputError
from spotnav.setup.config import Setup, setup_from_dict, toml_data
from spotnav.setup.uncertainty import Uncertainty
from spotnav.setup.values import SetupError

__all__ = ["CLAIMS_EXACT_GEOMETRY", "read_opencv_camera", "read_setup", "setup_to_dict", "setup_to_toml"]


def read_setup(path: str | Path, *, report: Callable[[str], None] | None = None, localizing: bool = False) -> Setup:
    """Read and validate a TOML setup file.

    The file gives the contract's keys (:func:`spotnav.setup.config.missing_keys`): one that lacks any (a section
    left out, a file cut short) is an error naming them. The other keys take spotnav's values (docs/setup.md); of
    those, ``[uncertainty]`` is a typical microscope's, not this one's: its keys that the file does not give are named
    in a warning, with the values assumed.

    Parameters
    ----------
    path : str or Path
    report : callable, optional
        Takes the warnings (default: stderr).
    localizing : bool
        The setup is to answer frames (``localize``, ``track``, ``show``; not the studies, which render from exact
        setups on purpose): a file that claims its geometry exactly (:attr:`Setup.claims_exact_geometry`) is said so
        in a warning, with the way to a real microscope's answers.

    Raises
    ------
    SetupError
        Naming the file, and the keys it lacks or the key of an invalid value (the line and column of a byte that is
        not UTF-8).
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as error:
        raise SetupError(f"{path}: cannot read the setup: {error.strerror or error}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise SetupError(f"{path}: {_not_utf8(data, error.start)}") from None
    try:
        tables = toml_data(text)
        setup = setup_from_dict(tables, complete=True)
    except SetupError as error:
        raise SetupError(f"{path}: {error}") from None
    say = report or partial(print, file=sys.stderr)
    assumed = _assumed_uncertainty(tables.get("uncertainty"))
    if assumed:
        say(f"spotnav: warning: {path} {assumed}")
    if localizing and setup.claims_exact_geometry:
        say(f"spotnav: warning: {path} {CLAIMS_EXACT_GEOMETRY}")
    return setup


CLAIMS_EXACT_GEOMETRY = (
    "claims its geometry exactly (every [uncertainty] value 0, no [calibration]), as only a simulation rendered "
    "from it can: a microscope's frames would be answered ok with a sigma_mm below their error; at a microscope, "
    "leave [uncertainty] out (a real microscope's) and run spotnav calibrate on frames with the tip at known points "
    '(README, "Use")'
)
"""What a setup that claims exact geometry is told, after its file's name, when it is to answer frames."""


def _assumed_uncertainty(table: Mapping[str, Any] | None) -> str:
    """What of ``[uncertainty]`` a setup file leaves to a typical microscope's values (``table``: the section as
    given, None without it), said after the file's name; ``""`` when it gives every key."""
    defaults = Uncertainty()
    names = [item.name for item in fields(Uncertainty) if table is None or item.name not in table]
    if not names:
        return ""
    what = "[uncertainty]" if table is None else ", ".join(f"uncertainty.{name}" for name in names)
    values = ", ".join(f"{name} {getattr(defaults, name):g}" for name in names)
    return (
        f"does not give {what}: assuming a typical microscope's ({values}), not this one's; the precise methods "
        "refuse the poses it makes too uncertain (uncalibrated) until spotnav calibrate measures the geometry"
    )


def _not_utf8(data: bytes, start: int) -> str:
    """Where in ``data`` the byte at ``start`` breaks UTF-8, as a person finds it: line and column (1-based)."""
    line_start = data.rfind(b"\n", 0, start) + 1
    column = len(data[line_start:start].decode("utf-8", "replace")) + 1
    line = data.count(b"\n", 0, start) + 1
    return f"line {line}, column {column}: byte 0x{data[start]:02x} is not UTF-8 (TOML files are UTF-8)"


def setup_to_dict(setup: Setup) -> dict[str, Any]:
    """The setup as plain data (for JSON)."""
    return asdict(setup)


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
