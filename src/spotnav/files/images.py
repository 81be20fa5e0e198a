"""Reading and writing one image file: its size from the header, the oversized-image rule, and the pixels.

:func:`read_image` checks the size in a file's header before anything is decoded, by one rule whatever the size:
first against the setup's camera (status ``wrong_size``), then against :data:`MAX_IMAGE_BYTES` (``unreadable``). It
tells a truncated PNG before decoding it and keeps OpenCV's and libpng's own messages off stderr, then reads 8- or
16-bit grey, RGB or RGBA; every failure is an :class:`ImageReadError` with a one-line message that names the file and
the ``poses.csv`` status of its row.
"""

from __future__ import annotations

import contextlib
import os
import struct
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np
import PIL.Image
import PIL.ImageFile

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

    Each of Pillow's format plugins that accepts the file's first bytes parses the header in turn, as
    ``PIL.Image.open`` does but without its decompression-bomb limit: any size in a header is read, so that one
    rule judges it (:func:`read_image`).

    Raises
    ------
    ImageReadError
        If the file cannot be opened (missing, a directory, a symlink loop, no permission).
    """
    PIL.Image.init()  # every plugin registered (Pillow imports them on first use)
    try:
        with open(path, "rb") as handle, warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a plugin's complaint about a damaged header (TIFF's EXIF), on stderr
            prefix = handle.read(16)
            for kind in PIL.Image.ID:
                factory, accept = PIL.Image.OPEN[kind]
                handle.seek(0)
                try:
                    verdict = accept(prefix) if accept is not None else True
                    if verdict and not isinstance(verdict, str):
                        with factory(handle, os.fsdecode(path)) as header:
                            return header.size
                # Not this plugin's format (as PIL.Image.open takes them), or a header it cannot parse: Pillow's
                # plugins raise a plain ValueError for that (PPM's tokens, PNG's chunks), no narrower class.
                except (SyntaxError, IndexError, TypeError, struct.error, ValueError, EOFError):
                    continue
    except OSError as error:
        raise _open_error(display_name(path), error) from None
    return None  # let OpenCV decide


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"  # the IEND chunk that closes every PNG


def _png_cut_short(data: np.ndarray) -> bool:
    """Whether ``data`` (a file's bytes) is a PNG whose chunks run past its end, before the closing IEND chunk.

    libpng, handed such a file, prints its own error on stderr; this walks the chunks' headers only (about 1 ms for a
    5000 px frame), and not at all when the file ends with IEND.
    """
    if data[:8].tobytes() != _PNG_SIGNATURE or data[-12:].tobytes() == _PNG_END:
        return False
    at = len(_PNG_SIGNATURE)
    while at + 8 <= data.size:
        length, kind = struct.unpack(">I4s", data[at : at + 8].tobytes())
        at += 12 + length  # length, type, data, CRC
        if kind == b"IEND":
            return bool(at > data.size)
    return True


@contextlib.contextmanager
def _opencv_quiet() -> Iterator[None]:
    """OpenCV's own log (a codec's warnings and errors on stderr) silenced; its failures still show as results."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(level)


def _wrong_size(name: str, size: Sequence[int], expected: Sequence[int]) -> ImageReadError:
    message = f"{name}: image is {size[0]}x{size[1]} px, the setup's camera is {expected[0]}x{expected[1]} px"
    return ImageReadError(message, "wrong_size")


def read_image(
    path: str | Path, *, expected_size: tuple[int, int] | None = None, max_bytes: int = MAX_IMAGE_BYTES
) -> np.ndarray:
    """Read an 8- or 16-bit image as grey, RGB or RGBA (not OpenCV's BGR).

    The size in the file's header is checked before anything is decoded, the same way whatever it is: first against
    ``expected_size`` (status ``wrong_size``), then against ``max_bytes`` (``unreadable``).

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
    if _png_cut_short(data):
        raise ImageReadError(
            f"{name}: truncated PNG: the file ends after {data.size} bytes, before its image data is complete "
            "(was it still being written or copied?)"
        )
    with _opencv_quiet():
        try:
            image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        except cv2.error:
            image = None
    if image is None and size is not None:
        raise ImageReadError(
            f"{name}: its header reads {size[0]}x{size[1]} px, but its pixels cannot be decoded "
            "(a truncated or damaged file)"
        )
    if image is None:
        raise ImageReadError(f"{name}: not an image OpenCV can read")
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
