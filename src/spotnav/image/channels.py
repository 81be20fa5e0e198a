"""A frame's values as grey levels and as light: the 8-bit grey image that spot detection thresholds (also of a frame
shrunk by whole cells, in one compiled pass), the decoding of each code to linear light by the camera's response,
and the channel the edge reader reads (the brightest that does not clip).
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
from numba import njit

from spotnav.optics.response import decoding_table, encoding_table

__all__ = ["linear_luminance", "to_gray8"]


_GREY_WEIGHTS = (9798, 19235, 3735)  # OpenCV's 8-bit RGB to grey: 0.299, 0.587 and 0.114 in 15-bit fixed point
_TO_EIGHT_BITS = np.float32(255.0 / 65535.0)  # 16 bits to 8, in single precision (as NumPy scales a float32 array)


def to_gray8(image: np.ndarray, response: str | float = "srgb") -> np.ndarray:
    """8-bit sRGB-encoded grey image (as a display shows it) from grey, RGB or RGBA, 8 or 16 bits.

    Parameters
    ----------
    image : ndarray, shape (H, W), (H, W, 3) or (H, W, 4), uint8 or uint16
        Colour images are RGB(A).
    response : str or float
        How the frame's values relate to light (``camera.response``): another
        response than ``"srgb"`` is decoded and encoded again as sRGB.

    Returns
    -------
    ndarray, shape (H, W), uint8

    Raises
    ------
    ValueError
        For any other shape or dtype.
    """
    if response != "srgb":
        light = np.minimum(linear_luminance(image, response), 1.0)
        encoded: np.ndarray = encoding_table("srgb", 8)[np.round(light * 65535.0).astype(np.uint16)]
        return encoded
    if image.dtype == np.uint16:
        image = (image.astype(np.float32) * _TO_EIGHT_BITS + np.float32(0.5)).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise ValueError(f"image must be 8-bit or 16-bit, got {image.dtype}")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_RGBA2GRAY)
    raise ValueError(f"image must be grey, RGB or RGBA, got shape {image.shape}")


def _shrunk_gray(image: np.ndarray, decimate: int, response: str | float, *, one_row: bool = False) -> np.ndarray:
    """The frame shrunk by ``decimate`` (the whole cells), then made 8-bit grey (:func:`to_gray8`).

    Each cell is the mean of its 2 x 2 middle pixels (bilinear at its centre), or with ``one_row`` of the 2 middle
    pixels of its upper middle row (half a pixel above the centre): the frame's memory is read only there, a
    quarter of it at 4.

    Parameters
    ----------
    image : ndarray, shape (H, W), (H, W, 3) or (H, W, 4)
        8 or 16 bits (another type is refused by :func:`to_gray8`).
    decimate : int
    response : str or float
        ``camera.response``.
    one_row : bool

    Returns
    -------
    ndarray, shape (H // decimate, W // decimate), uint8
    """
    if decimate > 1 and image.dtype in (np.uint8, np.uint16) and image.ndim in (2, 3):
        height, width = image.shape[0] // decimate, image.shape[1] // decimate
        if min(height, width) < 1:
            raise ValueError(f"decimate {decimate} leaves no pixel of a {image.shape[1]}x{image.shape[0]} image")
        # Shrunk before the grey conversion (less to convert): every pixel of a cell at 2, and no full pass over a
        # 5000 px frame at 4.
        if one_row:
            channels = image if image.ndim == 3 else image[:, :, None]
            count = channels.shape[2]
            grey = response == "srgb" and count in (1, 3, 4)  # to_gray8's own, in the same pass: no second one
            cells = np.empty((height, width, 1 if grey else count), dtype=np.uint8 if grey else image.dtype)
            _one_row_means(channels, decimate, (0,) * count, cells, grey)
            if grey:
                return cells[:, :, 0]
            image = cells[:, :, 0] if count == 1 else cells
        else:
            whole = image[: height * decimate, : width * decimate]
            image = cv2.resize(whole, (width, height), interpolation=cv2.INTER_LINEAR)
    return to_gray8(image, response)


_BLOCK_ROWS = 8  # rows read side by side: their first touches of memory overlap instead of waiting in turn


@njit(cache=True)
def _one_row_means(image: np.ndarray, decimate: int, channels: tuple[int, ...], cells: np.ndarray, grey: bool) -> None:
    """The cells (H', W', C) of ``image`` (H, W, C), H' = H // decimate and W' = W // decimate, read in one row each,
    as OpenCV's bilinear ``resize`` reads the rows ``decimate // 2 - 1 :: decimate`` at the cells' centres: the mean
    of the 2 middle pixels (one, for an odd ``decimate``) of each cell's row, rounded half up for 8 bits and half to
    even for 16 (as OpenCV rounds them), written into ``cells`` (H', W', C) of ``image``'s type. With ``grey`` each
    cell is written as :func:`to_gray8` makes an sRGB frame grey instead (16 bits to 8, then OpenCV's weights; one
    or three or four channels), into ``cells`` (H', W', 1) of 8 bits: the same bits, in the same pass.

    OpenCV reads the rows one after the other, each a fresh start in memory that the next waits on;
    ``_BLOCK_ROWS`` rows are read side by side here (0.31 -> 0.27 ms at 2048 px, just after another method read the
    frame). ``channels`` is a tuple of C zeros: its length is the compiler's to unroll.
    """
    height, width = image.shape[0] // decimate, image.shape[1] // decimate
    row, left, right = decimate // 2 - 1, (decimate - 1) // 2, decimate // 2
    wide = image.itemsize == 2  # 16 bits
    for block in range(0, height, _BLOCK_ROWS):
        for j in range(width):
            for i in range(block, min(block + _BLOCK_ROWS, height)):
                v, u = i * decimate + row, j * decimate
                if not grey:
                    for c in range(len(channels)):
                        cells[i, j, c] = _pair_mean(image[v, u + left, c], image[v, u + right, c], wide)
                    continue
                weighted: int | np.int64 = 0
                for c in range(min(len(channels), 3)):
                    level = _pair_mean(image[v, u + left, c], image[v, u + right, c], wide)
                    if wide:
                        level = np.int64(np.float32(level) * _TO_EIGHT_BITS + np.float32(0.5))
                    weighted += level if len(channels) == 1 else _GREY_WEIGHTS[c] * level
                cells[i, j, 0] = weighted if len(channels) == 1 else (weighted + (1 << 14)) >> 15


@njit(cache=True, inline="always")
def _pair_mean(first: int, second: int, half_even: bool) -> np.int64:
    """The mean of two pixel values, rounded half up, or with ``half_even`` half to even."""
    total = np.int64(first) + np.int64(second)
    mean = (total + 1) >> 1
    if half_even and total & 3 == 1:
        mean -= 1  # halfway to an odd value: down to the even one
    return mean


# The decoding tables are monotonic: clipping (at the first code at full scale, see _decoding) and brightness can
# be judged on the codes.
_FULL_SCALE_LINEAR = 0.99
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)  # Rec. 709, on linear values


def _decoding(image: np.ndarray, response: str | float) -> tuple[np.ndarray, int]:
    """The frame's decoding table (linear light per code) and its first code at full scale.

    Full scale is the code that light at full scale is written as (a tone
    curve may never reach the top code), or the first that decodes to
    ``_FULL_SCALE_LINEAR`` if that comes first.
    """
    if image.dtype == np.uint8:
        return _decoding_of_bits(response, 8)
    if image.dtype == np.uint16:
        return _decoding_of_bits(response, 16)
    raise ValueError(f"image must be 8-bit or 16-bit, got {image.dtype}")


@lru_cache(maxsize=16)
def _decoding_of_bits(response: str | float, bits: int) -> tuple[np.ndarray, int]:
    """:func:`_decoding` for ``bits`` per value, once per response (every tracked frame asks)."""
    table = decoding_table(response, bits)
    return table, min(int(np.searchsorted(table, _FULL_SCALE_LINEAR)), int(encoding_table(response, bits)[-1]))


def linear_luminance(image: np.ndarray, response: str | float = "srgb") -> np.ndarray:
    """Linear luminance of a frame, full scale 1.

    Parameters
    ----------
    image : ndarray, shape (H, W), (H, W, 3) or (H, W, 4), uint8 or uint16
        Grey or RGB(A).
    response : str or float
        How its values relate to light (``camera.response``): ``"srgb"``, as
        the built-in renderer and Blender's standard view transform write,
        ``"linear"`` or a gamma.

    Returns
    -------
    ndarray, shape (H, W), float32
    """
    linear: np.ndarray = _decoding(image, response)[0][image]
    if linear.ndim == 2:
        return linear
    if linear.ndim == 3 and linear.shape[2] in (3, 4):
        return linear[..., :3] @ _LUMINANCE
    raise ValueError(f"image must be grey, RGB or RGBA, got shape {image.shape}")


_CHANNEL_GRID = 128  # the brightest channel is judged on about this many pixels a side (every other, up to 256 px)


@njit(cache=True)
def _linear_crop(
    image: np.ndarray, full_scale: int, centre: np.ndarray, reach: float
) -> tuple[np.ndarray, np.ndarray, bool, int]:
    """The pixels of ``image`` (H, W, C) within ``reach`` of ``centre`` (clipped to the image) in one channel.

    The channel is the brightest that never clips there (else the least
    clipped one): a clipped channel bends the profile where it clips, while
    another channel still holds the edge's true shape. A tone curve may write
    full scale below the top code (AgX-like: 242 of 255), and ``full_scale``
    is the code where it clips. Returns the crop of that channel (a view),
    ``centre`` in the crop's pixels, whether any channel clipped, and the channel.
    """
    height, width = image.shape[0], image.shape[1]
    u0, v0 = max(int(np.floor(centre[0] - reach)) - 1, 0), max(int(np.floor(centre[1] - reach)) - 1, 0)
    u1 = min(int(np.ceil(centre[0] + reach)) + 2, width)
    v1 = min(int(np.ceil(centre[1] + reach)) + 2, height)
    crop = image[v0:v1, u0:u1]
    channel, saturated = _brightest_channel(crop, full_scale)
    return crop[:, :, channel], np.array([centre[0] - u0, centre[1] - v0]), saturated, channel


@njit(cache=True)
def _brightest_channel(crop: np.ndarray, full_scale: int) -> tuple[int, bool]:
    """Which channel (of the first three) of ``crop`` (H, W, C) to read, and whether any channel clips.

    The brightest that never reaches ``full_scale``, else the least clipped
    one, judged on every other pixel of every other row, or on a sparser grid
    of about ``_CHANNEL_GRID`` pixels a side in a larger crop (the edge's own
    clipping is measured on the rays).
    """
    height, width, channels = crop.shape[0], crop.shape[1], min(crop.shape[2], 3)
    step = max(2, min(height, width) // _CHANNEL_GRID)
    brightest, clipped = np.zeros(channels, dtype=np.int64), np.zeros(channels, dtype=np.int64)
    for first in range(0, height, step * _BLOCK_ROWS):
        for u in range(0, width, step):
            for v in range(first, min(first + step * _BLOCK_ROWS, height), step):
                for c in range(channels):
                    brightest[c] = max(brightest[c], crop[v, u, c])
                    clipped[c] += crop[v, u, c] >= full_scale
    chosen = int(np.argmin(clipped))
    for c in range(channels):
        if clipped[c] == 0 and (clipped[chosen] > 0 or brightest[c] > brightest[chosen]):
            chosen = c
    return chosen, clipped.sum() > 0
