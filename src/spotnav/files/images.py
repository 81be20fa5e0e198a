"""Reading and writing one image file: its size from the header, the oversized-image rules, and the pixels.

:func:`read_image` checks the size in a file's header before anything is decoded (against the setup's camera, and
against :data:`MAX_IMAGE_BYTES`) and reads 8- or 16-bit grey, RGB or RGBA; every failure is an
:class:`ImageReadError` with a one-line message that names the file and the ``poses.csv`` status of its row.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import PIL.Image

from spotnav.errors import InputError

__all__ = ["MAX_IMAGE_BYTES", "ImageReadError", "display_name", "image_size", "read_image", "write_image"]


class ImageReadError(InputError):
    """An image file is missing, empty, too large, not an image, or not the camera's size.

    ``status`` is the ``poses.csv`` status of its row: ``unreadable`` or ``wrong_size``.
    """

    def __init__(self, message: str, status: str = "unreadable") -> None:
        super().__init__(message)
        self.status = status


MAX_IMAGE_BYTES = 1 << 30  # the most memory one decoded image may take (8 bytes a pixel at most: RGBA, 16 bits)


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
        limit = PIL.Image.MAX_IMAGE_PIXELS
        if limit is None:  # impossible: Pillow raises this error only against a set limit
            raise
        raise ImageReadError(f"{name}: its header claims over {2 * limit} pixels") from None
    except PIL.UnidentifiedImageError:
        return None
    except OSError as error:
        raise _open_error(name, error) from None
    # A header Pillow cannot parse: let OpenCV decide. Pillow's plugins raise a plain ValueError for it (PPM's
    # tokens, PNG's chunks), no narrower class.
    except (ValueError, SyntaxError):
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
