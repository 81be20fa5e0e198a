"""Spot detection: the thesis's (section 5.3, Algorithm 1) and spotnav's sub-pixel edges.

The thesis's: grey conversion, median blur, Gaussian blur, Otsu threshold and
``findContours`` without approximation; contours of more than 5 points.
spotnav's precise method starts from those contours and locates each spot's
edge to a fraction of a pixel along rays (:func:`detect_edge_subpixel`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache

import cv2
import numpy as np
from numba import njit

from spotnav.image.photometry import EdgeLight, fit_clipped_edges, ray_bands
from spotnav.optics.camera import decoding_table, encoding_table
from spotnav.optics.edgeblur import (
    EDGE_SMOOTHING_PX,
    frame_blur_for_width,
    frame_blur_shift,
    full_width_at_half_maximum,
    response_curve,
    seen_edge,
)
from spotnav.optics.pixelnoise import new_noise_pool, pooled_frame_blur

__all__ = [
    "Spot",
    "SpotDetection",
    "SpotEdge",
    "curve_rays",
    "detect_edge_along_rays",
    "detect_edge_subpixel",
    "detect_spots_otsu",
    "edge_window_px",
    "group_fragments",
    "linear_luminance",
    "otsu_threshold",
    "outer_boundary",
    "rays_around_spot",
    "rays_through_curve",
    "to_gray8",
]

_MIN_CONTOUR_POINTS = 5
_MIN_AREA_FRACTION = 0.1  # blobs smaller than this fraction of the largest are clutter
_BACKGROUND_DISC_PX = 16  # the broad background is opened on a grid where its disc is about this wide
_HULL_TOLERANCE_PX = 1.5  # a contour point this close to the convex hull is on the outer boundary
_GROUP_RMS_PX = 1.5  # fragments whose outer boundaries an ellipse fits this well (or ...
_GROUP_RMS_FRACTION = 0.03  # ... to this fraction of its radius) are one spot
_MAX_FRAGMENTS = 32  # the largest regions grouped: 12 vessels cut a spot into some 20
_SUSPECTS = 3  # a group that does not fit tries leaving out this many of its worst-fitting regions
_MIN_CONTRAST_DN = 6.0
_GREY_WEIGHTS = (9798, 19235, 3735)  # OpenCV's 8-bit RGB to grey: 0.299, 0.587 and 0.114 in 15-bit fixed point
_TO_EIGHT_BITS = np.float32(255.0 / 65535.0)  # 16 bits to 8, in single precision (as NumPy scales a float32 array)


@dataclass(frozen=True)
class Spot:
    """One bright region.

    Attributes
    ----------
    contour_px : ndarray, shape (N, 2)
        Boundary pixels ``(u, v)``, as ``findContours`` returns them (from a
        shrunk frame: the shrunk pixels' centres, in the frame's pixels).
    area_px : float
        Enclosed area in pixels.
    touches_border : bool
        Whether the region reaches the image's edge (the spot is cut).
    """

    contour_px: np.ndarray
    area_px: float
    touches_border: bool


@dataclass(frozen=True)
class SpotDetection:
    """Result of spot detection.

    Attributes
    ----------
    spots : tuple of Spot
        Significant regions, largest first; empty when no spot is seen.
    threshold : float
        Otsu's threshold on the blurred 8-bit grey image.
    contrast : float
        Mean grey level of the largest region minus the background's median, in
        grey levels (0 when nothing was found).
    fragments : int
        How many bright regions were found (:func:`group_fragments`); 0: not
        grouped, one region per spot.
    """

    spots: tuple[Spot, ...]
    threshold: float
    contrast: float
    fragments: int = 0

    @property
    def regions(self) -> str:
        """What was seen, for messages: ``"4 bright regions in 3 spots"`` or ``"3 bright regions"``."""
        regions = max(self.fragments, len(self.spots))
        plural = "s" if regions != 1 else ""
        spots = "" if regions == len(self.spots) else f" in {len(self.spots)} spot{'s' if len(self.spots) != 1 else ''}"
        return f"{regions} bright region{plural}{spots}"


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
        return encoding_table("srgb", 8)[np.round(light * 65535.0).astype(np.uint16)]
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


@njit(cache=True)
def _background_level(histogram: np.ndarray, threshold: int) -> tuple[int, float]:
    """The background's level and robust spread from a histogram (256,) of grey levels: the median and 1.4826 times
    the median absolute deviation of the levels up to ``threshold``."""
    below = histogram.copy()
    below[threshold + 1 :] = 0
    median = _histogram_median(below)
    deviations = np.zeros(256, dtype=np.int64)
    for level in range(256):
        deviations[abs(level - median)] += below[level]
    return median, 1.4826 * _histogram_median(deviations)


@njit(cache=True)
def _histogram_median(histogram: np.ndarray) -> int:
    """Median level of a histogram (256,) of integer counts: the first whose count reaches half of all (the lower one
    on a tie)."""
    total, cumulative = np.sum(histogram), 0
    for level in range(len(histogram)):
        cumulative += histogram[level]
        if 2 * cumulative >= total:
            return level
    return len(histogram) - 1


def detect_spots_otsu(
    image: np.ndarray,
    blur_px: int = 5,
    min_contrast_sigma: float = 6.0,
    response: str | float = "srgb",
    min_area_fraction: float = _MIN_AREA_FRACTION,
    background_px: int = 0,
    decimate: int = 1,
    refine: tuple[int, int] | None = None,
) -> SpotDetection:
    """Find the bright spots as the thesis does.

    Parameters
    ----------
    image : ndarray
        Grey, RGB or RGBA, 8 or 16 bits (see :func:`to_gray8`).
    blur_px : int
        Odd kernel size of the median and Gaussian blurs.
    min_contrast_sigma : float
        A spot must stand out from the background's median by this many of the
        background's robust standard deviations (and by 6 grey levels).
    response : str or float
        How the frame's values relate to light (``camera.response``).
    min_area_fraction : float
        Regions smaller than this fraction of the largest are clutter (the
        fragments of a spot that vessels cut need a smaller one).
    background_px : int
        When positive, a broad background (an endo-illuminator's glow) is
        estimated and removed first: the grey image opened with a disc this
        wide (wider than any spot), which keeps only what is broader.
    decimate : int
        Detect on the frame shrunk by this factor (its encoded values averaged
        over the 2 x 2 middle pixels of each cell, then made grey; all of a
        cell at 2): the coarse outlines of spots many
        pixels wide, at a fraction of the cost. ``blur_px`` is in the shrunk
        image's pixels; ``background_px`` and the returned contours (through
        the shrunk pixels' centres) and areas are in the frame's.
    refine : tuple of int, optional
        ``(decimate, blur_px)`` of a second pass, ``decimate`` a divisor of the
        first's: the regions found are outlined again on the frame shrunk by
        that smaller factor, with the first pass's threshold and background,
        only in boxes around them (:func:`_outlined_again`). That gives the
        outlines of the finer shrink at about the cost of the coarser. The
        first pass then reads one row of each cell of 4 or more rows; the
        threshold and contrast returned are its own.

    Returns
    -------
    SpotDetection
    """
    if decimate < 1:
        raise ValueError(f"decimate must be >= 1, got {decimate}")
    if refine is not None and not (1 <= refine[0] <= decimate and decimate % refine[0] == 0):
        raise ValueError(f"refine's decimate must divide decimate {decimate}, got {refine[0]}")
    refined = refine is not None and refine[0] < decimate
    # Finding the spots reads one row of each cell of 4 or more rows (a quarter of the memory at 4): at 2 (frames of
    # about 1000 px, 3 MB) it would save little and leave out half the pixels.
    gray = _shrunk_gray(image, decimate, response, one_row=refined and decimate >= 4)
    grid = None
    if background_px > 0:
        grid = _broad_background(gray, max(background_px // decimate, 1))
        gray = cv2.subtract(gray, cv2.resize(grid, (gray.shape[1], gray.shape[0]), interpolation=cv2.INTER_LINEAR))
    blurred = cv2.GaussianBlur(cv2.medianBlur(gray, blur_px), (blur_px, blur_px), 0)
    histogram, sampled = _histograms(blurred)
    threshold = otsu_threshold(histogram)
    _, binary = cv2.threshold(blurred, threshold, 255, cv2.THRESH_BINARY)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    contours = [c.reshape(-1, 2) for c in contours if len(c) > _MIN_CONTOUR_POINTS]
    if not contours:
        return SpotDetection((), float(threshold), 0.0)
    areas = _areas(contours, decimate)
    largest = int(areas.argmax())
    left, top, box_width, box_height = cv2.boundingRect(contours[largest])
    mask = np.zeros((box_height, box_width), dtype=np.uint8)
    cv2.drawContours(mask, contours, largest, 255, thickness=cv2.FILLED, offset=(-left, -top))
    median, spread = _background_level(sampled, threshold)  # every other pixel of every other row
    contrast = float(cv2.mean(blurred[top : top + box_height, left : left + box_width], mask)[0] - median)
    min_area = max(20.0, 1e-5 * gray.size * decimate**2)
    if areas[largest] < min_area or contrast < max(_MIN_CONTRAST_DN, min_contrast_sigma * spread):
        return SpotDetection((), float(threshold), contrast)
    shape = gray.shape
    if refine is not None and refined:
        kept = [c for c, area in zip(contours, areas, strict=True) if area >= min_area_fraction * areas[largest]]
        contours = _outlined_again(image, kept, decimate, refine, response, threshold, grid)
        decimate, shape = refine[0], (image.shape[0] // refine[0], image.shape[1] // refine[0])
        areas = _areas(contours, decimate)
    order = np.argsort(-areas)
    spots = tuple(
        Spot(
            contour_px=(contours[i] + 0.5) * decimate - 0.5,  # a shrunk pixel's centre in the frame's pixels
            area_px=float(areas[i]),
            touches_border=_reaches_frame_edge(contours[i], shape),
        )
        for i in order
        if areas[i] >= min_area_fraction * areas[order[0]]
    )
    return SpotDetection(spots, float(threshold), contrast)


def _merged_boxes(boxes: list[list[int]]) -> list[list[int]]:
    """Boxes, those that overlap merged into one.

    Parameters
    ----------
    boxes : list of list of int
        Each ``[left, top, right, bottom]``, pixels, right and bottom exclusive.

    Returns
    -------
    list of list of int
        The same form, no two overlapping.
    """
    merged = [list(box) for box in boxes]
    joined = True
    while joined:
        joined = False
        for i in range(len(merged)):
            for j in range(i + 1, len(merged)):
                a, b = merged[i], merged[j]
                if a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]:
                    merged[i] = [min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])]
                    del merged[j]
                    joined = True
                    break
            if joined:
                break
    return merged


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
def _one_row_means(image: np.ndarray, decimate: int, channels: tuple, cells: np.ndarray, grey: bool) -> None:
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
                weighted = 0
                for c in range(min(len(channels), 3)):
                    level = _pair_mean(image[v, u + left, c], image[v, u + right, c], wide)
                    if wide:
                        level = np.int64(np.float32(level) * _TO_EIGHT_BITS + np.float32(0.5))
                    weighted += level if len(channels) == 1 else _GREY_WEIGHTS[c] * level
                cells[i, j, 0] = weighted if len(channels) == 1 else (weighted + (1 << 14)) >> 15


@njit(cache=True, inline="always")
def _pair_mean(first: int, second: int, half_even: bool) -> int:
    """The mean of two pixel values, rounded half up, or with ``half_even`` half to even."""
    total = np.int64(first) + np.int64(second)
    mean = (total + 1) >> 1
    if half_even and total & 3 == 1:
        mean -= 1  # halfway to an odd value: down to the even one
    return mean


def _areas(contours: Sequence[np.ndarray], decimate: int) -> np.ndarray:
    """The areas (N,) of contours on a frame shrunk by ``decimate``, in the frame's pixels.

    A shrunk contour runs half a shrunk pixel inside the spot (not half a pixel): the strip between them along its
    length is added.
    """
    strip = 0.5 * decimate * (decimate - 1)
    return np.array([decimate**2 * cv2.contourArea(c) + strip * cv2.arcLength(c, True) for c in contours])


def _outlined_again(
    image: np.ndarray,
    contours: Sequence[np.ndarray],
    decimate: int,
    refine: tuple[int, int],
    response: str | float,
    threshold: int,
    grid: np.ndarray | None,
) -> list[np.ndarray]:
    """The outlines (N, 2 each) of the bright regions in boxes around ``contours`` (of the frame shrunk by
    ``decimate``), on the frame shrunk by ``refine = (decimate, blur_px)`` instead, in its shrunk pixels.

    Each box reaches two coarse pixels and two blur kernels beyond its contour; boxes that overlap are one. In each,
    the broad background (``grid``, as :func:`_broad_background` gives it for the coarse frame, or None) is
    removed, the grey image blurred and cut at ``threshold``, as the coarse pass did on the whole frame. A region
    that reaches a box's side inside the frame (a bright structure too thin for the coarse pass) would be cut
    there: that box is widened by its own size on every side, and the boxes are outlined again.
    """
    fine, blur_px = refine
    factor = decimate // fine
    shape = (image.shape[0] // fine, image.shape[1] // fine)
    margin = 2 * factor + 2 * blur_px
    boxes = []
    for contour in contours:
        left, top, box_width, box_height = cv2.boundingRect(contour)
        box = [left * factor, top * factor, (left + box_width) * factor, (top + box_height) * factor]
        boxes.append(_widened(box, (margin, margin), shape))
    boxes = _merged_boxes(boxes)

    def outlines_in(box: list[int]) -> list[np.ndarray]:
        """The outlines in one ``box`` (left, top, right, bottom, in the finer frame's shrunk pixels)."""
        left, top, right, bottom = box
        gray = _shrunk_gray(image[top * fine : bottom * fine, left * fine : right * fine], fine, response)
        if grid is not None:
            # The grid stretched over the coarse frame (as cv2.resize does), sampled at the box's fine pixels.
            scale_u = fine / decimate * grid.shape[1] / (image.shape[1] // decimate)
            scale_v = fine / decimate * grid.shape[0] / (image.shape[0] // decimate)
            to_grid = np.array(
                [[scale_u, 0.0, scale_u * (left + 0.5) - 0.5], [0.0, scale_v, scale_v * (top + 0.5) - 0.5]]
            )
            size = (gray.shape[1], gray.shape[0])
            flags, border = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, cv2.BORDER_REPLICATE
            gray = cv2.subtract(gray, cv2.warpAffine(grid, to_grid, size, flags=flags, borderMode=border))
        blurred = cv2.GaussianBlur(cv2.medianBlur(gray, blur_px), (blur_px, blur_px), 0)
        _, binary = cv2.threshold(blurred, threshold, 255, cv2.THRESH_BINARY)
        found, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        return [c.reshape(-1, 2) + np.array([left, top]) for c in found if len(c) > _MIN_CONTOUR_POINTS]

    while True:
        outlines, grown = [], []
        for box in boxes:
            found = outlines_in(box)
            outlines += found
            cut = any(_reaches_inner_side(outline, box, shape) for outline in found)
            grown.append(_widened(box, (box[2] - box[0], box[3] - box[1]), shape) if cut else box)
        if grown == boxes:
            return outlines
        boxes = _merged_boxes(grown)


def _widened(box: list[int], by: tuple[int, int], shape: tuple[int, int]) -> list[int]:
    """``box`` (left, top, right, bottom) widened by ``by`` (across, down) on each side, within a frame of ``shape``
    (height, width), all in the same pixels."""
    left, top, right, bottom = box
    return [max(left - by[0], 0), max(top - by[1], 0), min(right + by[0], shape[1]), min(bottom + by[1], shape[0])]


def _reaches_frame_edge(outline: np.ndarray, shape: tuple[int, int]) -> bool:
    """Whether ``outline`` (N, 2) touches an edge of a frame of ``shape`` (height, width)."""
    first_u, first_v, width, height = cv2.boundingRect(outline)
    return first_u == 0 or first_v == 0 or first_u + width == shape[1] or first_v + height == shape[0]


def _reaches_inner_side(outline: np.ndarray, box: list[int], shape: tuple[int, int]) -> bool:
    """Whether ``outline`` (N, 2) touches a side of ``box`` (left, top, right, bottom) that is not the frame's edge
    (the frame ``shape`` is (height, width)), all in the same shrunk pixels."""
    left, top, right, bottom = box
    first_u, first_v, width, height = cv2.boundingRect(outline)
    return (
        (left > 0 and first_u == left)
        or (top > 0 and first_v == top)
        or (right < shape[1] and first_u + width == right)
        or (bottom < shape[0] and first_v + height == bottom)
    )


@njit(cache=True)
def _histograms(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How many pixels of ``gray`` (H, W), uint8, have each level (256,), and how many of every other pixel of
    every other row (256,), in one pass.

    Four interleaved counts: neighbouring pixels of one level would otherwise wait on each other's count.
    """
    counts, sampled = np.zeros((4, 256), dtype=np.int64), np.zeros((2, 256), dtype=np.int64)
    width = gray.shape[1]
    for v in range(gray.shape[0]):
        row, u = gray[v], 0
        while u + 3 < width:
            first, second, third, fourth = row[u], row[u + 1], row[u + 2], row[u + 3]
            counts[0, first] += 1
            counts[1, second] += 1
            counts[2, third] += 1
            counts[3, fourth] += 1
            if v % 2 == 0:
                sampled[0, first] += 1
                sampled[1, third] += 1
            u += 4
        while u < width:
            counts[0, row[u]] += 1
            if v % 2 == 0 and u % 2 == 0:
                sampled[0, row[u]] += 1
            u += 1
    return counts.sum(axis=0), sampled.sum(axis=0)


_FLOAT32_EPSILON = float(np.finfo(np.float32).eps)


@njit(cache=True)
def otsu_threshold(histogram: np.ndarray) -> int:
    """Otsu's threshold of a histogram of the levels 0 to 255 (256,): the level that, with the levels up to it as
    one class, maximises the variance between the classes (the first such level; as OpenCV's ``THRESH_OTSU``, but
    for exact ties, which OpenCV's build with Intel's IPP may break for a later level)."""
    total = max(float(np.sum(histogram)), 1.0)
    mean = 0.0
    for level in range(256):
        mean += level * histogram[level] / total
    below, moment, best, threshold = 0.0, 0.0, 0.0, 0
    for level in range(256):
        share = histogram[level] / total
        below += share
        moment += level * share
        above = 1.0 - below
        if min(below, above) < _FLOAT32_EPSILON or max(below, above) > 1.0 - _FLOAT32_EPSILON:
            continue
        between = below * above * (moment / below - (mean - moment) / above) ** 2
        if between > best:
            best, threshold = between, level
    return threshold


def _broad_background(gray: np.ndarray, width_px: int) -> np.ndarray:
    """What is broader than ``width_px`` in ``gray`` (uint8): its opening by a disc that wide, on a coarse grid.

    Returns the grid (uint8), to be stretched over ``gray``.
    """
    scale = max(1, width_px // _BACKGROUND_DISC_PX)
    coarse = (max(gray.shape[1] // scale, 1), max(gray.shape[0] // scale, 1))
    whole = gray[: coarse[1] * scale, : coarse[0] * scale]  # whole cells: OpenCV's fast path
    small = cv2.resize(whole, coarse, interpolation=cv2.INTER_AREA)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * (width_px // (2 * scale)) + 1,) * 2)
    opened = _opening(small, disc).astype(np.float32)
    # Blurred in floats: OpenCV's exact 8-bit blur takes five times as long with a kernel this wide.
    return cv2.GaussianBlur(opened, (0, 0), width_px / (4.0 * scale)).round().astype(np.uint8)


_ROW_ALIGN_PX = 16  # OpenCV's morphology runs 2.5 times as fast on 8-bit rows a multiple of this long (51 px: 79 us)


def _opening(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """``cv2.morphologyEx(image, cv2.MORPH_OPEN, kernel)`` of an 8-bit ``image`` (H, W), the same bits, on rows padded
    to a multiple of ``_ROW_ALIGN_PX``: the pad takes no part (full scale in the erosion, zero in the dilation), as
    pixels beyond the image take none in OpenCV's."""
    width = image.shape[1]
    padded = cv2.copyMakeBorder(image, 0, 0, 0, -width % _ROW_ALIGN_PX, cv2.BORDER_CONSTANT, value=255)
    eroded = cv2.erode(padded, kernel)
    eroded[:, width:] = 0
    return cv2.dilate(eroded, kernel)[:, :width]


def _near_hull(points_px: np.ndarray, tolerance_px: float) -> np.ndarray:
    """Which of ``points_px`` (N, 2) lie within ``tolerance_px`` of their convex hull's boundary (N,)."""
    hull = cv2.convexHull(points_px.astype(np.float32)).reshape(-1, 2).astype(float)
    if len(hull) < 3:
        return np.ones(len(points_px), dtype=bool)
    return _near_sides(np.asarray(points_px, dtype=float), hull, tolerance_px)


@njit(cache=True)
def _near_sides(points_px: np.ndarray, hull: np.ndarray, tolerance_px: float) -> np.ndarray:
    """Which of ``points_px`` (N, 2), inside the convex polygon ``hull`` (H, 2), lie within ``tolerance_px`` of a
    side's line: the distance to the boundary of a point inside is the least to a side's line.

    Each point's search starts at the side the last point found near was near: along a contour, usually its own.
    """
    count = len(hull)
    sides, lengths = np.empty((count, 2)), np.empty(count)
    for h in range(count):
        sides[h, 0], sides[h, 1] = hull[(h + 1) % count, 0] - hull[h, 0], hull[(h + 1) % count, 1] - hull[h, 1]
        lengths[h] = max(np.hypot(sides[h, 0], sides[h, 1]), 1e-9)
    near = np.zeros(len(points_px), dtype=np.bool_)
    last = 0
    for n in range(len(points_px)):
        for k in range(count):
            h = (last + k) % count
            offset_u, offset_v = points_px[n, 0] - hull[h, 0], points_px[n, 1] - hull[h, 1]
            if abs(sides[h, 0] * offset_v - sides[h, 1] * offset_u) / lengths[h] <= tolerance_px:
                near[n], last = True, h
                break
    return near


def _ellipse_distances(points_px: np.ndarray, ellipse: tuple) -> np.ndarray:
    """Approximate distances (N,) of ``points_px`` (N, 2) from an ellipse as ``cv2.fitEllipse`` gives it, pixels.

    Along the ray from the ellipse's centre: ``(rho - 1) r / rho`` with ``rho``
    the point's normalised radius and ``r`` its distance from the centre.
    """
    (cu, cv), (width, height), angle = ellipse
    cos, sin = np.cos(np.radians(angle)), np.sin(np.radians(angle))
    du, dv = points_px[:, 0] - cu, points_px[:, 1] - cv
    x, y = cos * du + sin * dv, -sin * du + cos * dv
    rho = np.hypot(x / max(width / 2.0, 1e-9), y / max(height / 2.0, 1e-9))
    return (rho - 1.0) * np.hypot(x, y) / np.maximum(rho, 1e-9)


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2))) if len(values) else 0.0


_GROUP_KERNEL_PX = 8  # group_fragments grows regions on a grid where half the gap is at most about this


def group_fragments(
    detection: SpotDetection, shape: tuple[int, int], gap_px: float, whole_area_px: float
) -> SpotDetection:
    """Bright regions grouped into spots: regions whose outer boundaries lie on one ellipse together are one spot.

    A cone's spot is convex and close to an ellipse; dark vessels across it
    cut it into fragments whose outer boundaries still lie on that ellipse,
    while the boundaries of two spots (or of a spot and a glint beside it) do
    not. Regions less than ``gap_px`` apart (a vessel's width) are one
    cluster. A cluster is one spot when the ellipse fitted to its contour
    points near its convex hull fits them within ``_GROUP_RMS_PX`` or
    ``_GROUP_RMS_FRACTION`` of its mean radius (RMS), and at most one of its
    regions is a whole spot by itself (:func:`_is_whole`); otherwise the region
    whose removal fits best leaves it, until the rest fits, and the regions
    that left are grouped alike. A grouped spot's contour is those points,
    its area its convex hull's.

    Parameters
    ----------
    detection : SpotDetection
        Regions found with a small ``min_area_fraction`` (the fragments).
    shape : tuple of int
        The image's ``(height, width)``.
    gap_px : float
        The widest gap between two fragments of one spot, pixels.
    whole_area_px : float
        The smallest area a whole spot may have, pixels: a region this large
        that an ellipse fits is a spot, never a fragment of one.

    Returns
    -------
    SpotDetection
        Spots largest first (made of the ``_MAX_FRAGMENTS`` largest regions;
        those under ``_MIN_AREA_FRACTION`` of the largest dropped as clutter),
        with ``fragments`` the regions found.
    """
    regions = detection.spots[:_MAX_FRAGMENTS]  # largest first: the rest (noise, dust) is clutter
    if len(regions) < 2:
        return replace(detection, fragments=len(detection.spots))
    # Regions closer than the gap touch once each grows by half of it: on a grid coarse enough that the
    # growing kernel stays under _GROUP_KERNEL_PX (a 70 px kernel over a 5000 px frame took 1.8 s).
    reach_px = max(gap_px / 2.0, 1.0)
    scale = max(1, int(reach_px // _GROUP_KERNEL_PX))
    labels = np.zeros((-(-shape[0] // scale), -(-shape[1] // scale)), dtype=np.uint8)
    for region in regions:
        cv2.fillPoly(labels, [np.round((region.contour_px + 0.5) / scale - 0.5).astype(np.int32)], 255)
    reach = max(int(np.ceil(reach_px / scale)), 1)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1, 2 * reach + 1))
    _, clusters = cv2.connectedComponents(cv2.dilate(labels, kernel))
    first = [np.round((r.contour_px[0] + 0.5) / scale - 0.5).astype(int) for r in regions]
    cluster_of = [int(clusters[min(v, labels.shape[0] - 1), min(u, labels.shape[1] - 1)]) for u, v in first]
    spots: list[Spot] = []
    for cluster in sorted(set(cluster_of)):
        members = [r for r, c in zip(regions, cluster_of, strict=True) if c == cluster]
        while members:
            group, members = _ellipse_group(members, whole_area_px)
            spots.append(group[0] if len(group) == 1 else _merged(group))
    spots.sort(key=lambda spot: -spot.area_px)
    kept = tuple(spot for spot in spots if spot.area_px >= _MIN_AREA_FRACTION * spots[0].area_px)
    return replace(detection, spots=kept, fragments=len(detection.spots))


def _is_whole(region: Spot, whole_area_px: float) -> bool:
    """Whether a region is a whole spot by itself: at least ``whole_area_px`` large, and an ellipse fits its
    whole contour (not only its outer points) within ``_GROUP_RMS_FRACTION`` of its radius, or a pixel."""
    if region.area_px < whole_area_px or len(region.contour_px) < _MIN_CONTOUR_POINTS:
        return False
    ellipse = cv2.fitEllipseDirect(region.contour_px.astype(np.float32))
    tolerance = max(1.0, _GROUP_RMS_FRACTION * 0.25 * (ellipse[1][0] + ellipse[1][1]))
    return _rms(_ellipse_distances(region.contour_px.astype(float), ellipse)) <= tolerance


def _ellipse_group(members: list[Spot], whole_area_px: float) -> tuple[list[Spot], list[Spot]]:
    """The regions of ``members`` that make one spot (see :func:`group_fragments`), and the others."""
    group, others = list(members), []
    whole = [_is_whole(region, whole_area_px) for region in group]
    while len(group) > 1:
        errors = _ellipse_errors(group)
        if errors.max() <= 1.0 and sum(whole) <= 1:
            break
        # Of the regions that fit worst (and the whole spots, when there are two), the one whose removal fits best.
        suspects = set(np.argsort(-errors)[:_SUSPECTS].tolist()) | (
            {i for i, w in enumerate(whole) if w} if sum(whole) > 1 else set()
        )
        worst = min(suspects, key=lambda i: _ellipse_errors(group[:i] + group[i + 1 :]).max())
        others.append(group.pop(worst))
        whole.pop(worst)
    return group, others


def _outer_points(group: Sequence[Spot]) -> tuple[np.ndarray, np.ndarray]:
    """The group's contour points near its convex hull, and which region (index in ``group``) each came from."""
    points = np.concatenate([spot.contour_px for spot in group]).astype(float)
    owner = np.concatenate([np.full(len(spot.contour_px), i) for i, spot in enumerate(group)])
    near = _near_hull(points, _HULL_TOLERANCE_PX)
    return points[near], owner[near]


def _ellipse_errors(group: Sequence[Spot]) -> np.ndarray:
    """How far each region's outer points lie from the ellipse the group's fit, RMS over the tolerance (len(group),).

    The tolerance is ``_GROUP_RMS_PX`` or ``_GROUP_RMS_FRACTION`` of the
    ellipse's mean radius; a region with no outer point scores 0.
    """
    points, owner = _outer_points(group)
    if len(points) < _MIN_CONTOUR_POINTS:
        return np.full(len(group), np.inf)
    ellipse = cv2.fitEllipseDirect(points.astype(np.float32))
    tolerance = max(_GROUP_RMS_PX, _GROUP_RMS_FRACTION * 0.25 * (ellipse[1][0] + ellipse[1][1]))
    distances = _ellipse_distances(points, ellipse)
    return np.array([_rms(distances[owner == i]) for i in range(len(group))]) / tolerance


def _merged(group: Sequence[Spot]) -> Spot:
    """One spot from the fragments of ``group``: their outer boundary (in order around it), their hull's area."""
    points, _ = _outer_points(group)
    offsets = points - points.mean(axis=0)
    points = points[np.argsort(np.arctan2(offsets[:, 1], offsets[:, 0]))]  # in order around the spot
    hull = cv2.convexHull(points.astype(np.float32))
    return Spot(points, float(cv2.contourArea(hull)), any(spot.touches_border for spot in group))


def outer_boundary(spot: Spot, tolerance_px: float = _HULL_TOLERANCE_PX) -> Spot:
    """The spot with only the convex part of its contour: the boundary that no occluder carved.

    A cone's spot is convex; where something opaque in front of it (the
    instrument's shaft, a dark vessel) cuts into it, its contour turns inward.
    The contour points within ``tolerance_px`` of the contour's convex hull
    are kept (all of them for a convex spot), in order.

    Parameters
    ----------
    spot : Spot
    tolerance_px : float

    Returns
    -------
    Spot
        With ``contour_px`` reduced (at least 5 points, else the spot unchanged).
    """
    outer = spot.contour_px[_near_hull(spot.contour_px.astype(float), tolerance_px)]
    if len(outer) < _MIN_CONTOUR_POINTS:
        return spot
    return replace(spot, contour_px=outer)


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
    linear = _decoding(image, response)[0][image]
    if linear.ndim == 2:
        return linear
    if linear.ndim == 3 and linear.shape[2] in (3, 4):
        return linear[..., :3] @ _LUMINANCE
    raise ValueError(f"image must be grey, RGB or RGBA, got shape {image.shape}")


@dataclass(frozen=True)
class SpotEdge:
    """A spot's boundary located to a fraction of a pixel.

    Attributes
    ----------
    pixels : ndarray, shape (N, 2)
        Edge points ``(u, v)``, one per valid ray, in ray order around the spot.
    ray_angles : ndarray, shape (N,)
        Direction of each point's ray from the spot's centre, radians.
    width_px : float
        Width of the edge, pixels: full width at half maximum of the median
        profile's slope (its ends interpolated), after the detector's
        smoothing (:data:`spotnav.optics.edgeblur.EDGE_SMOOTHING_PX`).
    saturated : bool
        Whether any channel reaches full scale around the spot (on every other pixel of every other row).
    rays : int
        Rays cast; ``len(pixels)`` of them gave an edge.
    contrast_to_noise : float
        Median step across the edge over the pixel noise, on the rays with an
        edge (NaN without any): below some 20 the noise biases the edge's level.
    clipped_fraction : float
        Fraction of the samples inside the edge, where the plateau's line is
        fitted, at full scale in the channel read: a clipped plateau lowers the
        halfway level and moves the edge outward.
    plateau, background : float
        The median profile's plateau and background at the edge, linear light
        (full scale 1).
    dark_rays : int
        Rays on the image left out: no light's edge on them, or one that a
        structure (a vessel, the shaft, a glint) shaped.
    misshapen_rays : int
        Of those, rays whose light's edge fell otherwise than the spot's (a
        vessel along the edge): the light is there, its edge not read.
    log_amplitude, blur_px : float
        Where the plateau clips, the photometric model's amplitude (natural
        log of the plateau's light, full scale 1) and blur (pixels)
        (:func:`spotnav.image.photometry.fit_clipped_edges`); NaN elsewhere.
    flank_shift_px : float
        How far the spot's edge may lie off as a whole (1 sigma, pixels): the
        clipped rays' shift that the amplitude's uncertainty leaves, times
        their share of the edge's points; 0 where nothing clips.
    frame_blur_px, frame_blur_sigma_px : float
        The blur of the encoded frame (a Gaussian's sigma, pixels) that the
        noise beside the spot shows, and its 1 sigma
        (:func:`spotnav.optics.pixelnoise.frame_blur_from_noise`; a tracked stream's
        from its last frames, :func:`spotnav.optics.pixelnoise.pooled_frame_blur`): 0 for white noise;
        NaN where the noise is too faint to tell.
    frame_shift_px, frame_shift_sigma_px : float
        How far that blur moved the half-light crossing (outward positive,
        pixels; :func:`spotnav.optics.edgeblur.frame_blur_shift`), taken out of the
        edge's points where the half level read them, and its 1 sigma; NaN
        where the blur or the beam's band is not known. A clipped spot's
        flank is read with the blur in its model
        (:func:`spotnav.image.photometry.fit_clipped_edges`): there, the shift of
        the edge's curvature alone.
    """

    pixels: np.ndarray
    ray_angles: np.ndarray
    width_px: float
    saturated: bool
    rays: int
    contrast_to_noise: float = float("nan")
    clipped_fraction: float = 0.0
    plateau: float = float("nan")
    background: float = float("nan")
    dark_rays: int = 0
    misshapen_rays: int = 0
    log_amplitude: float = float("nan")
    blur_px: float = float("nan")
    flank_shift_px: float = 0.0
    frame_blur_px: float = float("nan")
    frame_blur_sigma_px: float = float("nan")
    frame_shift_px: float = float("nan")
    frame_shift_sigma_px: float = float("nan")


_STEP_PX = 0.5
_REFIT_CLIPPED = 0.02  # of the plateau's samples at full scale: the half level is gone, the photometric model reads
_MIN_FLANK_SAMPLES = 1  # a clipped spot's ray needs this many samples on its unclipped flank
_MIN_BAND_PX = 1.0  # a clipped spot whose soft band is narrower has no flank beyond the pixels' own blur: left out
_NO_MODEL, _NO_LIGHT = np.zeros(0), np.zeros(0)  # no light to read a clipped spot with
_NOISE_GAP_WIDTHS = 2.5  # the noise is read from this many edge widths past the edge (the background's lines) ...
_NOISE_RING_PX = 12.0  # ... over a ring this wide, below this share of the way from background to plateau:
_NOISE_LIT = 0.25
_FRAME_SHIFT_MODEL = 0.15  # how far the edge model's shift may be off, of itself
_CURVED_MODEL = 0.25  # how far a blurred curve's shift may be off, of itself (an ellipse's curvature varies)
_COARSE_LEVEL = 0.2
_PROFILE_RAYS = 64  # the median profile is taken over about this many rays
_NOISE_RAYS = 32  # the noise from the steps along about this many rays (a few thousand steps)
_COARSE_SAMPLES = 64
_COARSE_RAY_STRIDE = 2
_EDGE_MEDIAN_RAYS = 5  # coarse rays, about 9 rays
_RAY_SPACING_PX = 1.0  # along the spot's outline: vessels leave short arcs of edge between them
_HYSTERESIS = 0.1  # of the step: a fall through the halfway level runs from this far above it to this far below
_LIT = 0.3  # a ray whose plateau is darker than this of the brightest rays' lies under a dark structure
_DARK_DIP = 0.5  # of the contrast: a ray's profile that dips this deep near its edge was shaped by a dark structure
_NEAR_DARK_WIDTHS = 0.5  # rays this many edge widths ...
_NEAR_DARK_PX = 1.0  # ... and pixels along the edge from a dark structure's are left out
# A ray whose fall lies a share d of the contrast from the spot's, over a fall w pixels wide, has its half-light
# crossing moved by about d w: a structure shaped it (a vessel along the edge darkens the fall but not the plateau)
# where that is over this, beyond four noises. A flat fundus's rays lie within 0.02 of their median (1024 px, w about
# 3 px); on the procedural retina, rays whose edges lay over 0.5 px off had a median of 0.10.
_FALL_SHIFT_PX = 0.15
_MIN_FALL_PX = 3.0  # ... on edges this wide or wider: a narrower fall is the pixels' footprint's, which differs by ray
_MISSHAPEN_RUN_PX = 2.0  # along the edge: a vessel along it shapes a run of rays this long; shorter, the texture
_MAX_MISSHAPEN = 0.5  # of the rays judged: more, and the median fall is no spot's
_MIN_JUDGED = 0.5  # of the rays on the image: the falls are judged only where this many have an edge
_FALL_REFERENCE_RAYS = 16  # the spot's soft band from about this many rays
# The frame's blur after its encoding (from its noise) beyond which the falls are not judged: at 1.5 px (384 px) the
# rays left out were those the blur shaped, and the rest gave a tip 0.13 mm off at 5 sigma; at 1 px (1024 px) the
# test still leaves out the rays a vessel shaped (88 % of 16 helix tips within 3 sigma, against 81 %).
_MAX_FALL_TEST_BLUR_PX = 1.25
# A blur the noise tells this uncertainly (1 sigma) is read in the other channels too: on a dark fundus, a 2 px blur
# left the spot's channel's estimate 0.4-0.6 px uncertain.
_UNCERTAIN_BLUR_PX = 0.2
# A clipped flank read with the frame's blur: its window grows by this many of the blur's sigmas (2 px, thesis's
# exposure, 1024 px: tips 0.020-0.027 mm off, against 0.022-0.036 in the unblurred flank's window).
_FRAME_BLUR_WINDOW = 4.0
# ... and its blur may be off by this share of itself beside the noise's sigma: the noise's blur runs high where the
# long lags see texture (1.6-1.8 px told for 1.5), and the model along the ray leaves the edge outward as it grows.
_FRAME_BLUR_MODEL = 0.15
_NOISE_POOL_SHAPE = new_noise_pool(1).shape


def detect_edge_subpixel(
    image: np.ndarray,
    spot: Spot,
    response: str | float = "srgb",
    *,
    max_rays: int = 2048,
    light: EdgeLight | None = None,
) -> SpotEdge:
    """Locate a spot's edge to a fraction of a pixel, independently of the light's power.

    Rays are cast from the centre of the spot's coarse (Otsu) boundary across
    it, one per ``_RAY_SPACING_PX`` of perimeter (64 to ``max_rays``); see :func:`detect_edge_along_rays`.

    Parameters
    ----------
    image : ndarray
        The frame (see :func:`linear_luminance`).
    spot : Spot
        The spot's coarse detection.
    response : str or float
        How the frame's values relate to light (``camera.response``).
    max_rays : int
        Most rays (at least 64).

    Returns
    -------
    SpotEdge
    """
    return detect_edge_along_rays(image, *rays_around_spot(spot, max_rays), response=response, light=light)


def rays_around_spot(spot: Spot, max_rays: int = 2048) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rays :func:`detect_edge_subpixel` reads a spot's edge on: from the centre of its coarse boundary, one per
    ``_RAY_SPACING_PX`` of its perimeter (64 to ``max_rays``), as :func:`rays_through_curve` returns them."""
    if max_rays < 64:
        raise ValueError(f"max_rays must be at least 64, got {max_rays}")
    perimeter = float(cv2.arcLength(spot.contour_px.astype(np.float32).reshape(-1, 1, 2), True))
    rays = int(min(max(perimeter / _RAY_SPACING_PX, 64), max_rays))
    return rays_through_curve(spot.contour_px.astype(float), rays)


def rays_through_curve(curve_px: np.ndarray, rays: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Evenly spaced rays from a closed curve's centroid, and where each meets the curve.

    Parameters
    ----------
    curve_px : ndarray, shape (N, 2)
        Points ``(u, v)`` on a closed curve that is star-shaped about its centroid.
    rays : int

    Returns
    -------
    centre : ndarray, shape (2,)
    ray_angles : ndarray, shape (rays,)
        Directions, radians, from -pi.
    radii : ndarray, shape (rays,)
        Distance from the centre to the curve along each ray, pixels.
    """
    curve_px = np.ascontiguousarray(curve_px, dtype=float)
    if curve_px.ndim != 2 or curve_px.shape[1] != 2 or len(curve_px) == 0:
        raise ValueError(f"curve_px must have shape (N, 2) with N >= 1, got {curve_px.shape}")
    return curve_rays(curve_px, int(rays))


@njit(cache=True)
def curve_rays(curve_px: np.ndarray, rays: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`rays_through_curve`, compiled: the curve's radius interpolated linearly in angle, periodically."""
    centre = np.array([np.mean(curve_px[:, 0]), np.mean(curve_px[:, 1])])
    count = len(curve_px)
    curve_angles = np.arctan2(curve_px[:, 1] - centre[1], curve_px[:, 0] - centre[0])
    order = np.argsort(curve_angles)
    angles = np.empty(count + 2)  # the sorted angles with the last before -pi and the first after pi
    radii_sorted = np.empty(count + 2)
    for i in range(count):
        n = order[i]
        angles[i + 1] = curve_angles[n]
        radii_sorted[i + 1] = np.hypot(curve_px[n, 0] - centre[0], curve_px[n, 1] - centre[1])
    angles[0], radii_sorted[0] = angles[count] - 2.0 * np.pi, radii_sorted[count]
    angles[count + 1], radii_sorted[count + 1] = angles[1] + 2.0 * np.pi, radii_sorted[1]
    ray_angles = np.empty(rays)
    radii = np.empty(rays)
    for r in range(rays):
        ray_angles[r] = -np.pi + 2.0 * np.pi * r / rays
    radii[:] = np.interp(ray_angles, angles, radii_sorted)
    return centre, ray_angles, radii


def detect_edge_along_rays(
    image: np.ndarray,
    centre: np.ndarray,
    ray_angles: np.ndarray,
    radii: np.ndarray,
    *,
    align: bool = False,
    response: str | float = "srgb",
    light: EdgeLight | None = None,
    noise_pool: np.ndarray | None = None,
) -> SpotEdge:
    """Locate an edge to a fraction of a pixel on rays that cross it near ``radii``.

    On each ray the linear luminance (of the brightest channel that does not
    clip) is lightly smoothed; straight lines are fitted to the plateau inside
    the edge and to the background outside it, and the edge is put where a
    line through the profile's outermost fall crosses the level halfway
    between them (:func:`_crossing`). Levels relative to the local plateau and
    background do not move when the power changes, and the lines follow the
    light's fall-off across the edge. The edge's width (from the median
    profile of the lit rays) sets where the lines are fitted. Rays without a
    clear crossing give no point, nor do rays a structure shaped (a plateau off
    its line, a dip where the edge falls) or that lie next to a ray under a
    dark structure; that erosion takes the rays to be evenly spaced around the
    whole spot. Only the pixels near the rays are read: the rays are the
    region of interest.

    With ``align`` the edge may lie anywhere within twice that distance of
    ``radii`` (a spot that moved since ``radii`` were predicted): a coarse
    pass over every second ray finds each ray's outermost fall through the
    level a fifth of the way from its lowest to its highest value (outside a
    spot there is only background, while a lit vessel stays above that
    level), with a running median over neighbouring rays against the clutter
    that remains; the fine pass is then centred there. The rays must then go
    around the spot in order.

    Parameters
    ----------
    image : ndarray
        The frame (see :func:`linear_luminance`).
    centre : ndarray, shape (2,)
        The rays' origin ``(u, v)``, pixels.
    ray_angles : ndarray, shape (R,)
        Ray directions, radians.
    radii : ndarray, shape (R,)
        Expected distance of the edge from ``centre`` on each ray, pixels; the
        rays are sampled within ``0.15 * mean(radii) + 8`` pixels of it.
    align : bool
        Find each ray's edge coarsely first (see above).
    response : str or float
        How the frame's values relate to light (``camera.response``).
    light : EdgeLight, optional
        The beam's light model (:func:`spotnav.image.photometry.edge_light`): a
        clipped spot's rays are read from their flank with it.
    noise_pool : ndarray, optional
        A stream's noise beside this spot over its last frames
        (:func:`spotnav.optics.pixelnoise.new_noise_pool`, advanced for each new
        frame): the blur of the encoded frame is told from them together and
        this frame reads a share of its ring. Without it, the ring is read whole.

    Returns
    -------
    SpotEdge

    Raises
    ------
    ValueError
        If ``centre`` is not a finite (2,), or the angles and radii are not
        finite arrays of one length, or ``noise_pool`` is not a pool.
    """
    # Own copies: the compiled call then always sees writable, contiguous arrays (one signature).
    angles, radii = np.array(ray_angles, dtype=float), np.array(radii, dtype=float)
    centre = np.array(centre, dtype=float)
    if centre.shape != (2,) or angles.ndim != 1 or angles.shape != radii.shape:
        raise ValueError(
            f"centre must be (2,), ray_angles and radii (R,), got {centre.shape}, {angles.shape}, {radii.shape}"
        )
    if noise_pool is None:
        noise_pool = new_noise_pool(1)
    elif not (
        noise_pool.ndim == 3
        and noise_pool.shape[::2] == _NOISE_POOL_SHAPE[::2]
        and noise_pool.shape[1] >= 1
        and noise_pool.dtype == np.float64
        and noise_pool.flags.c_contiguous
        and noise_pool.flags.writeable
    ):
        raise ValueError(f"noise_pool must come from new_noise_pool, got {noise_pool.dtype} {noise_pool.shape}")
    lut, full_scale = _decoding(image, response)
    channels = image if image.ndim == 3 else image[:, :, None]
    (
        pixels,
        kept,
        width,
        saturated,
        ratio,
        clipped,
        plateau,
        background,
        left_out,
        misshapen,
        amplitude,
        blur,
        shift,
        encoded,
    ) = _edge_on_rays(
        channels,
        lut,
        full_scale,
        centre,
        angles,
        radii,
        align,
        _NO_MODEL if light is None else light.model,
        _NO_LIGHT if light is None else light.light,
        response_curve(response),
        noise_pool,
    )
    return SpotEdge(
        pixels,
        angles[kept],
        width * _STEP_PX,
        saturated,
        len(angles),
        ratio,
        clipped,
        plateau,
        background,
        left_out,
        misshapen,
        amplitude,
        blur,
        shift,
        *(float(value) for value in encoded),
    )


@njit(cache=True)
def _edge_on_rays(
    image: np.ndarray,
    lut: np.ndarray,
    full_scale: int,
    centre: np.ndarray,
    angles: np.ndarray,
    radii: np.ndarray,
    align: bool,
    model: np.ndarray,
    light: np.ndarray,
    response: tuple[np.ndarray, np.ndarray],
    noise_pool: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, float, bool, float, float, float, float, int, int, float, float, float, np.ndarray]:
    """:func:`detect_edge_along_rays` on ``image`` (H, W, C), compiled: one call per spot.

    ``lut`` (codes,) is the light of each code and ``full_scale`` the first
    code at full scale (:func:`_decoding`); ``centre`` (2,) pixels, ``angles``
    (R,) radians, ``radii`` (R,) pixels; ``response`` the light and its
    encoded values (:func:`spotnav.optics.edgeblur.response_curve`); ``noise_pool``
    the stream's ring noise (:func:`spotnav.optics.pixelnoise.pooled_frame_blur`).
    Returns, in order: the edge points (N, 2) in pixels, the rays (N,) that gave them
    (indices), the edge's width in samples, whether any channel clipped,
    :func:`_read_edges`' contrast to noise, clipped fraction, plateau,
    background, rays left out and misshapen, log amplitude, blur and flank shift, and
    :func:`_encoded_blur`'s four values.
    """
    if not (np.isfinite(centre[0] + centre[1]) and np.all(np.isfinite(angles)) and np.all(np.isfinite(radii))):
        raise ValueError("centre, ray_angles and radii must be finite")
    window, wide = _window_px(radii, False), _window_px(radii, True)
    reach = np.max(radii) + (wide if align else window)
    pixels, offset, saturated, channel = _linear_crop(image, full_scale, centre, reach)
    if align:
        # Every _COARSE_RAY_STRIDE-th ray, _COARSE_SAMPLES samples across the wide window; the edge kept within
        # the fine window's reach (no pixel beyond the wide window is read).
        steps = _window_steps(wide, 2.0 * wide / _COARSE_SAMPLES)
        radii = _aligned_radii(pixels, lut, offset, angles, radii, steps, wide - window)
        window = _window_px(radii, False)  # about the edge found
    steps, top = _window_steps(window, _STEP_PX), lut[full_scale]
    read = _read_edges(pixels, lut, offset, angles, radii, steps, top, centre, model, light, (0.0, 0.0), response)
    # The noise beside the spot, out to _NOISE_RING_PX past its edge's outer side, tells a blur of the encoded
    # frame; its shift is taken out of the rays the half level read.
    encoded = _encoded_blur(
        image, channel, full_scale, centre, angles, read[0], read[1], read[2] * _STEP_PX, (read[5], read[6]),
        model, light, response, noise_pool,
    )  # fmt: skip
    reread = np.isfinite(read[9]) and np.isfinite(encoded[1]) and encoded[0] > 0.0 and read[1].any()
    if reread:
        # A clipped spot, the frame blurred after its encoding: the flank read again with that blur in its model.
        # The window grows with the blur: the flank's tail and the background past it.
        frame_blur = (encoded[0], np.hypot(encoded[1], _FRAME_BLUR_MODEL * encoded[0]))
        steps = _window_steps(window + _FRAME_BLUR_WINDOW * encoded[0], _STEP_PX)
        read = _read_edges(pixels, lut, offset, angles, radii, steps, top, centre, model, light, frame_blur, response)
    (edge_radii, valid, width, ratio, clipped, plateau, background, left_out, misshapen, amplitude, blur, shift) = read
    if reread and valid.any():
        # Blurred in two dimensions, a curved edge's levels move inward by the blur's square over twice its
        # radius, which the model along each ray leaves out: that is taken out as for the half level.
        curved = -(encoded[0] ** 2) / (2.0 * np.median(edge_radii[valid]))
        encoded[2], encoded[3] = curved, _CURVED_MODEL * abs(curved)
        edge_radii = edge_radii - curved
    elif np.isnan(amplitude) and np.isfinite(encoded[2]):
        edge_radii = edge_radii - encoded[2]
    if encoded[0] > _MAX_FALL_TEST_BLUR_PX:
        # Blurred after the encoding: the blur, not a structure, shaped the falls that differ (and smeared what a
        # vessel did to them); they are read.
        valid |= misshapen
        left_out -= int(misshapen.sum())
        misshapen = np.zeros_like(misshapen)
    kept = np.flatnonzero(valid)
    points = np.empty((len(kept), 2))
    for i in range(len(kept)):
        points[i, 0] = centre[0] + edge_radii[kept[i]] * np.cos(angles[kept[i]])
        points[i, 1] = centre[1] + edge_radii[kept[i]] * np.sin(angles[kept[i]])
    return (
        points,
        kept,
        width,
        saturated,
        ratio,
        clipped,
        plateau,
        background,
        left_out,
        int(misshapen.sum()),
        amplitude,
        blur,
        shift,
        encoded,
    )


@njit(cache=True)
def _encoded_blur(
    image: np.ndarray,
    channel: int,
    full_scale: int,
    centre: np.ndarray,
    angles: np.ndarray,
    edge_radii: np.ndarray,
    valid: np.ndarray,
    width_px: float,
    levels: tuple[float, float],
    model: np.ndarray,
    light: np.ndarray,
    response: tuple[np.ndarray, np.ndarray],
    noise_pool: np.ndarray,
) -> np.ndarray:
    """The blur of the encoded frame about a spot and the shift it gave the edge's half-light crossing.

    The blur comes from the noise in a ring beside the spot, pooled with the
    stream's last frames' in ``noise_pool``
    (:func:`spotnav.optics.pixelnoise.pooled_frame_blur`) in the edge's
    ``channel`` of the whole frame ``image`` (H, W, C); where that channel's
    background is too dark for its noise to tell (a clipped spot read in its
    least bright channel), in the channel whose noise tells it best; where
    it shows a blur but leaves it uncertain (over ``_UNCERTAIN_BLUR_PX``), with
    the other channels' that agree. The
    shift comes from the edge model at the spot's ``levels`` (plateau,
    background; linear light) and the beam's band on some of the ``valid`` rays (:func:`_reference_rays`)
    (:func:`spotnav.image.photometry.ray_bands`, the camera ``model`` and the
    beam's ``light``; :func:`spotnav.optics.edgeblur.seen_edge`) for the noise's
    blur, or the widest the edge's width allows where that is less.
    Returns (4,): the noise's blur and its 1 sigma (pixels; NaN where the
    noise does not tell), the shift (outward positive) and its 1 sigma
    (pixels: a quarter of the shift's range over blurs within two of the
    noise's sigmas and that bound, and ``_FRAME_SHIFT_MODEL`` of
    the shift; NaN without a band
    or a blur).
    """
    out = np.full(4, np.nan)
    if not valid.any():
        return out
    inner = np.median(edge_radii[valid]) + _NOISE_GAP_WIDTHS * width_px + 1.0
    light_grid, value_grid = response
    lit = levels[1] + _NOISE_LIT * (levels[0] - levels[1])  # brighter is another spot's light, not background
    ceiling = full_scale
    if np.isfinite(lit) and levels[0] > levels[1]:
        ceiling = min(int(np.interp(lit, light_grid, value_grid) * full_scale) + 1, full_scale)
    outer = inner + _NOISE_RING_PX
    out[0], out[1] = pooled_frame_blur(image[:, :, channel], channel, centre, inner, outer, ceiling, noise_pool)
    told = np.isfinite(out[0])
    if not told or (out[0] > 0.0 and out[1] > _UNCERTAIN_BLUR_PX):
        # Not told: the channel whose noise tells the blur best. Told uncertainly: the encoding blurs every channel
        # alike, and the blurs the other channels' noise shows that agree (within 3 sigmas; a codec that blurs its
        # colour more does not) are averaged in, each by its information. Their ceiling is their full scale.
        best, weights, total = np.inf, 1.0 / out[1] ** 2, out[0] / out[1] ** 2
        for other in range(image.shape[2]):
            if other == channel:
                continue
            blur, sigma = pooled_frame_blur(image[:, :, other], other, centre, inner, outer, full_scale, noise_pool)
            if not told and np.isfinite(blur) and sigma < best:
                out[0], out[1], best = blur, sigma, sigma
            elif told and blur > 0.0 and sigma > 0.0 and abs(blur - out[0]) < 3.0 * np.hypot(sigma, out[1]):
                weights += 1.0 / sigma**2
                total += blur / sigma**2
        if told:
            out[0], out[1] = total / weights, 1.0 / np.sqrt(weights)
    if len(light) == 0 or not levels[0] > levels[1]:
        return out
    some = _reference_rays(valid)  # the band varies slowly around the spot
    bands = ray_bands(model, light, centre, angles[some], edge_radii[some])
    bands = bands[np.isfinite(bands)]
    if len(bands) == 0:
        return out
    band = np.median(bands)
    unblurred_width, unblurred_crossing = seen_edge(levels[0], levels[1], band, 0.0, light_grid, value_grid)
    # Any blur, in light or of the frame, moves a curved edge inward: a disc of radius R blurred by a Gaussian of
    # sigma s has its half level about s^2 / (2 R) inside R. The blur is what widens the model edge to the edge's
    # width (in quadrature, a Gaussian's full width at half maximum being sqrt(8 ln 2) sigmas).
    blur_squared = max(width_px**2 - unblurred_width**2, 0.0) / (8.0 * np.log(2.0))
    curved = -blur_squared / (2.0 * np.median(edge_radii[valid]))
    if np.isnan(out[0]):
        # The noise does not tell which blur widened the edge: the shift halfway between a blur of the light (none)
        # and one of the encoded frame that alone widens the edge to its width (all of it, the most the frame can
        # have had), uncertain by half of it either way.
        widest = frame_blur_for_width(levels[0], levels[1], band, width_px, light_grid, value_grid)
        half = 0.5 * frame_blur_shift(levels[0], levels[1], band, widest, light_grid, value_grid)
        out[2] = half + curved
        out[3] = np.hypot(half, _CURVED_MODEL * curved)
        return out
    shift = spread = 0.0  # white noise: no blur of the encoded frame (one under some 0.4 px is not told from none)
    if out[0] > 0.0:
        # The noise's blur, no wider than the edge allows; uncertain by a quarter of the shifts' range over blurs
        # within two of the noise's sigmas and that bound (white noise needs no bound: bisecting it is a tenth of
        # a tracked frame at 2048 px).
        widest = frame_blur_for_width(levels[0], levels[1], band, width_px, light_grid, value_grid)
        high = min(out[0] + 2.0 * out[1], widest)
        low = min(max(out[0] - 2.0 * out[1], 0.0), high)
        shift = seen_edge(levels[0], levels[1], band, min(out[0], high), light_grid, value_grid)[1]
        nearer = seen_edge(levels[0], levels[1], band, low, light_grid, value_grid)[1]
        further = seen_edge(levels[0], levels[1], band, high, light_grid, value_grid)[1]
        shift, spread = shift - unblurred_crossing, 0.25 * abs(further - nearer)
    out[2] = shift + curved
    out[3] = np.hypot(np.hypot(spread, _FRAME_SHIFT_MODEL * shift), _CURVED_MODEL * curved)
    return out


@njit(cache=True)
def _window_steps(half_window: float, step: float) -> np.ndarray:
    """Samples every ``step`` pixels from ``-half_window`` to ``half_window``."""
    return np.arange(-half_window, half_window + step, step)


def edge_window_px(radii: np.ndarray, *, align: bool = False) -> float:
    """How far from ``radii`` (R,) :func:`detect_edge_along_rays` reads each ray, pixels (twice as far with
    ``align``)."""
    return float(_window_px(np.array(radii, dtype=float).ravel(), bool(align)))


@njit(cache=True)
def _window_px(radii: np.ndarray, align: bool) -> float:
    """:func:`edge_window_px`, compiled."""
    return (2.0 if align else 1.0) * (0.15 * np.mean(radii) + 8.0)


# The compiled kernels below read rays one sample at a time: a frame's few thousand samples cost
# microseconds, where array calls would cost tens of microseconds each (tracking's budget is 5 ms).
_SMOOTHING = cv2.getGaussianKernel(17, EDGE_SMOOTHING_PX / _STEP_PX).ravel()  # Gaussian of 2 samples' sigma


@njit(cache=True)
def _sample_rays(
    pixels: np.ndarray,
    lut: np.ndarray,
    offset: np.ndarray,
    ray_angles: np.ndarray,
    radii: np.ndarray,
    steps: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear samples (R, S) of the light ``lut[pixels]`` at ``offset + (radii + steps) * direction``, NaN off it.

    Also returns which rays (R,) lie wholly on the pixels.
    """
    height, width = pixels.shape
    profiles = np.full((len(ray_angles), len(steps)), np.nan)
    inside = np.zeros(len(ray_angles), dtype=np.bool_)
    if height < 2 or width < 2:
        return profiles, inside
    for r in range(len(ray_angles)):
        inside[r] = True
        cos, sin = np.cos(ray_angles[r]), np.sin(ray_angles[r])
        for s in range(len(steps)):
            u = offset[0] + (radii[r] + steps[s]) * cos
            v = offset[1] + (radii[r] + steps[s]) * sin
            if not (0.0 <= u <= width - 1 and 0.0 <= v <= height - 1):
                inside[r] = False
                continue
            iu, iv = min(int(u), width - 2), min(int(v), height - 2)
            fu, fv = u - iu, v - iv
            top = (1.0 - fu) * lut[pixels[iv, iu]] + fu * lut[pixels[iv, iu + 1]]
            bottom = (1.0 - fu) * lut[pixels[iv + 1, iu]] + fu * lut[pixels[iv + 1, iu + 1]]
            profiles[r, s] = (1.0 - fv) * top + fv * bottom
    return profiles, inside


@njit(cache=True)
def _smooth(
    values: np.ndarray, kernel: np.ndarray, start: int, stop: int, padded: np.ndarray, out: np.ndarray
) -> np.ndarray:
    """``values`` (S,) convolved with ``kernel`` (odd length), mirrored at the ends (``fedcba|abcdef|fedcba``),
    written into ``out`` (S,) and returned.

    Only samples ``start`` to ``stop`` (exclusive) are computed, the others are NaN; ``padded`` (at least
    S + len(kernel) - 1) is scratch. Rows shorter than half the kernel are mirrored once, then held.
    """
    count, half = len(values), len(kernel) // 2
    start = min(max(start, 0), count)
    stop = max(min(stop, count), start)
    for j in range(start, stop + 2 * half):  # only the padded samples the kernel reads
        i = j - half
        if i < 0:
            i = min(-i - 1, count - 1)
        elif i >= count:
            i = max(2 * count - i - 1, 0)
        padded[j] = values[i]
    out[:count] = np.nan
    # Taps outside, samples inside, indices counted from 0 (no negative-index checks): the inner loop vectorises.
    source, part = padded[start:], out[start:stop]
    part[:] = 0.0
    for k in range(len(kernel)):
        for i in range(len(part)):
            part[i] += kernel[k] * source[i + k]
    return out


@njit(cache=True)
def _fit_line(values: np.ndarray, start: float, stop: float) -> tuple[float, float]:
    """Least-squares line ``a + b * index`` through the samples with index in [start, stop] (at least two)."""
    count = len(values)
    first = min(max(int(np.ceil(start)), 0), count - 2)
    last = max(min(max(int(np.floor(stop)), 1), count - 1), first + 1)
    index_mean = 0.5 * (first + last)
    value_mean = np.mean(values[first : last + 1])
    covariance, variance = 0.0, 0.0
    for i in range(first, last + 1):
        covariance += (i - index_mean) * (values[i] - value_mean)
        variance += (i - index_mean) ** 2
    slope = covariance / variance
    return value_mean - index_mean * slope, slope


@njit(cache=True)
def _median(values: np.ndarray, scratch: np.ndarray) -> float:
    """The median of ``values`` (N >= 1, no NaN), as ``np.median``, selected in ``scratch`` (N or longer; may be
    ``values`` itself) without sorting or allocating."""
    n = len(values)
    for i in range(n):
        scratch[i] = values[i]
    upper = _select(scratch, n, n // 2)
    if n % 2:
        return upper
    lower = scratch[0]
    for i in range(1, n // 2):
        lower = max(lower, scratch[i])
    return 0.5 * (lower + upper)


# Up to this many values a selection partitions without branches on the values (Lomuto's scheme, each value moved
# by a conditional move): on a frame's medians of 38 and 64 values (the edge reader's, varied rays) 0.13 -> 0.07 ms,
# where Hoare's scheme mispredicts about one comparison in two. Past it, many equal values (steps between clipped
# samples, all zero) would make that scheme's passes quadratic.
_BRANCHLESS_SELECT_MAX = 64


@njit(cache=True)
def _select(values: np.ndarray, n: int, k: int) -> float:
    """The ``k``-th smallest of ``values[:n]``, in place: then ``values[:k]`` are no larger (Lomuto's selection
    without branches up to ``_BRANCHLESS_SELECT_MAX`` values, else Hoare's)."""
    low, high = 0, n - 1
    if n <= _BRANCHLESS_SELECT_MAX:
        while low < high:
            middle = (low + high) // 2
            pivot = values[middle]
            values[middle], values[high] = values[high], pivot
            store = low
            for i in range(low, high):
                value, stored = values[i], values[store]
                smaller = value < pivot
                values[store] = value if smaller else stored
                values[i] = stored if smaller else value
                store += smaller
            values[high], values[store] = values[store], pivot
            if k == store:
                return pivot
            if k < store:
                high = store - 1
            else:
                low = store + 1
        return values[k]
    while low < high:
        pivot = values[(low + high) // 2]
        i, j = low, high
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if k <= j:
            high = j
        elif k >= i:
            low = i
        else:
            break
    return values[k]


@njit(cache=True)
def _every_nth(selected: np.ndarray, n: int) -> np.ndarray:
    """Indices of every ``n``-th entry of ``selected`` (R,) that is True."""
    chosen = np.empty(len(selected), dtype=np.int64)
    count = 0
    for r in range(0, len(selected), n):
        if selected[r]:
            chosen[count] = r
            count += 1
    return chosen[:count]


@njit(cache=True)
def _crossing(
    smooth: np.ndarray,
    plateau: tuple[float, float],
    background: tuple[float, float],
    lo: int,
    hi: int,
    hysteresis: float,
) -> tuple[float, bool]:
    """Where ``smooth`` last falls through the level halfway between two lines, in samples [lo, hi].

    The outermost fall: a dark vessel inside the spot makes a fall before the
    light's edge, never after it. The fall runs from the last sample more
    than ``hysteresis`` above the level to the first after it more than
    ``hysteresis`` below; a line fitted to the samples between them crosses
    the level at the edge (noise and texture that wiggle about the level move
    it less than any one crossing). Returns the sample index (fractional) and
    whether there was a fall.
    """
    above = -1
    for i in range(lo, hi + 1):
        if smooth[i] - 0.5 * (plateau[0] + background[0] + (plateau[1] + background[1]) * i) > hysteresis:
            above = i
    if above < 0:
        return float(lo), False
    below = -1
    for i in range(above + 1, hi + 1):
        if smooth[i] - 0.5 * (plateau[0] + background[0] + (plateau[1] + background[1]) * i) < -hysteresis:
            below = i
            break
    if below < 0:
        return float(lo), False
    line = _fit_line(smooth, above, below)
    slope = line[1] - 0.5 * (plateau[1] + background[1])
    if not slope < 0:
        return float(lo), False
    where = (0.5 * (plateau[0] + background[0]) - line[0]) / slope
    return min(max(where, float(above)), float(below)), True


@njit(cache=True)
def _deepest_dip(values: np.ndarray, start: int, bottom: int, stop: int, scratch: np.ndarray) -> float:
    """How deep ``values`` dips with its lowest point between samples ``bottom`` and ``stop``.

    ``max_j min(max_{start<=i<=j} v_i - v_j, max_{j<=k<=stop} v_k - v_j)``
    over ``j`` in [bottom, stop]: the most it falls and then rises again; a
    light's edge falls without rising, a dark structure in front of it dips.
    ``scratch`` (at least stop - start + 1) holds the running maxima.
    """
    start, stop = max(start, 0), min(stop, len(values) - 1)
    bottom = min(max(bottom, start), stop)
    if stop <= start:
        return 0.0
    after = scratch
    after[stop - start] = values[stop]
    for j in range(stop - 1, start - 1, -1):
        after[j - start] = max(after[j - start + 1], values[j])
    before, deepest = values[start], 0.0
    for j in range(start, stop + 1):
        before = max(before, values[j])
        if j >= bottom:
            deepest = max(deepest, min(before, after[j - start]) - values[j])
    return deepest


@njit(cache=True)
def _line_deviation(values: np.ndarray, line: tuple[float, float], start: float, stop: float) -> float:
    """The largest distance of ``values`` from ``line`` (``a + b * index``) over the samples in [start, stop]."""
    largest = 0.0
    for i in range(max(int(np.ceil(start)), 0), min(int(np.floor(stop)), len(values) - 1) + 1):
        largest = max(largest, abs(values[i] - line[0] - line[1] * i))
    return largest


@njit(cache=True)
def _median_profile(
    profiles: np.ndarray, rays: np.ndarray, padded: np.ndarray, scratch: np.ndarray, start: int, stop: int
) -> tuple[np.ndarray, np.ndarray]:
    """The median over about ``_PROFILE_RAYS`` of the ``rays`` (R,) of their ``profiles`` (R, S), smoothed (S,),
    and minus its gradient (S,: central differences, one-sided at the ends), at samples ``start`` to ``stop``
    (exclusive; NaN elsewhere, and the gradient at a range's end inside the profile)."""
    count = profiles.shape[1]
    start, stop = max(start, 0), min(stop, count)
    half = len(_SMOOTHING) // 2
    chosen = _every_nth(rays, 1 + rays.sum() // _PROFILE_RAYS)
    column = np.empty(len(chosen))
    profile = np.full(count, np.nan)
    for s in range(max(start - half, 0), min(stop + half, count)):  # the samples the smoothing reads
        for j in range(len(chosen)):
            column[j] = profiles[chosen[j], s]
        profile[s] = _median(column, scratch)
    smooth = _smooth(profile, _SMOOTHING, start, stop, padded, np.empty(count))
    slope = np.full(count, np.nan)
    for s in range(start + 1, stop - 1):
        slope[s] = 0.5 * (smooth[s - 1] - smooth[s + 1])
    if start == 0:
        slope[0] = smooth[0] - smooth[1]
    if stop == count:
        slope[-1] = smooth[-2] - smooth[-1]
    return smooth, slope


@njit(cache=True)
def _aligned_fall(shares: np.ndarray, where: float, stretch: float, reach: int) -> np.ndarray:
    """A ray's fall at whole samples ``-reach..reach`` from its crossing ``where``, scaled by ``stretch``
    (2 reach + 1,).

    ``shares`` (S,) are the ray's samples as their share of the way from its
    background's line to its plateau's (NaN where not read); the fall is read
    at ``where + o stretch``, linearly interpolated (NaN off its read samples).
    """
    count = len(shares)
    seen = np.full(2 * reach + 1, np.nan)
    for o in range(-reach, reach + 1):
        at = where + o * stretch
        k = int(np.floor(at))
        if 0 <= k < count - 1:
            seen[o + reach] = shares[k] + (at - k) * (shares[k + 1] - shares[k])
    return seen


@njit(cache=True)
def _typical_fall(shares: np.ndarray, wheres: np.ndarray, rays: np.ndarray, reach: int) -> np.ndarray:
    """The median over ``rays`` of their :func:`_aligned_fall` (unscaled), NaN where none is known (2 reach + 1,)."""
    seen = np.empty((len(rays), 2 * reach + 1))
    for j in range(len(rays)):
        seen[j] = _aligned_fall(shares[rays[j]], wheres[rays[j]], 1.0, reach)
    typical = np.full(2 * reach + 1, np.nan)
    column, scratch = np.empty(len(rays)), np.empty(len(rays))
    for o in range(2 * reach + 1):
        kept = 0
        for j in range(len(rays)):
            if np.isfinite(seen[j, o]):
                column[kept] = seen[j, o]
                kept += 1
        if kept:
            typical[o] = _median(column[:kept], scratch)
    return typical


@njit(cache=True)
def _fall_distance(shares: np.ndarray, where: float, stretch: float, typical: np.ndarray) -> float:
    """The largest distance of one ray's :func:`_aligned_fall` (of ``typical``'s length, without building it) from
    the spot's ``typical`` (O,), where both are known."""
    count, reach = len(shares), len(typical) // 2
    largest = 0.0
    for o in range(-reach, reach + 1):
        at = where + o * stretch
        k = int(np.floor(at))
        if 0 <= k < count - 1 and np.isfinite(typical[o + reach]):
            seen = shares[k] + (at - k) * (shares[k + 1] - shares[k])
            if np.isfinite(seen):
                largest = max(largest, abs(seen - typical[o + reach]))
    return largest


@njit(cache=True)
def _misshapen_falls(
    shares: np.ndarray,
    wheres: np.ndarray,
    allowed: np.ndarray,
    valid: np.ndarray,
    width_px: float,
    step_px: float,
    centre: np.ndarray,
    ray_angles: np.ndarray,
    edge_radii: np.ndarray,
    model: np.ndarray,
    light: np.ndarray,
) -> np.ndarray:
    """Which ``valid`` rays (R,) fall otherwise than the spot's light, by more than their ``allowed`` share (R,).

    Each ray's fall (``shares`` (R, S), ``wheres`` (R,): :func:`_aligned_fall`)
    is compared, at whole samples (``step_px`` apart) from its own crossing
    within the edge's ``width_px``, with the median of about
    ``_PROFILE_RAYS`` valid rays'. A ray that crosses the edge aslant, or
    where the light meets the retina obliquely, falls wider by the geometry
    alone: a ray that differs is read again with its samples scaled by its
    expected fall's width over the spot's, the band's variance
    (:func:`spotnav.image.photometry.ray_bands` of the camera ``model`` and the
    beam's ``light`` from the frame's ``centre`` along ``ray_angles`` to
    ``edge_radii``, at about ``_FALL_REFERENCE_RAYS`` rays, the nearest one's around the spot;
    ``band^2 / 20`` for the smoothstep's slope) beside what the rays share
    (the pixels, the blurs and the smoothing: the measured width's variance
    less the spot's band's), and is misshapen only if it still differs.
    Without a ``light`` (empty) no ray is.
    """
    rays = len(wheres)
    odd = np.zeros(rays, dtype=np.bool_)
    kept = np.flatnonzero(valid)
    if len(light) == 0 or len(kept) == 0:
        return odd
    reference = _reference_rays(valid)
    ray_bands_at = ray_bands(model, light, centre, ray_angles[reference], edge_radii[reference])
    bands = ray_bands_at[np.isfinite(ray_bands_at)]
    if len(bands) == 0:
        return odd
    spot_band = np.median(bands) ** 2 / 20.0
    measured = width_px**2 / (8.0 * np.log(2.0))
    reach = int(np.ceil(width_px / step_px))
    typical = _typical_fall(shares, wheres, _every_nth(valid, 1 + len(kept) // _PROFILE_RAYS), reach)
    shared = max(measured - spot_band, 1.0 / 12.0 + EDGE_SMOOTHING_PX**2)
    for r in kept:
        odd[r] = _fall_distance(shares[r], wheres[r], 1.0, typical) > allowed[r]
        if not odd[r]:
            continue
        band, apart = np.nan, rays  # the nearest reference ray's, around the spot: the band varies slowly along it
        for j in range(len(reference)):
            gap = abs(reference[j] - r)
            gap = min(gap, rays - gap)
            if np.isfinite(ray_bands_at[j]) and gap < apart:
                band, apart = ray_bands_at[j], gap
        if np.isfinite(band):
            stretch = np.sqrt((band**2 / 20.0 + shared) / (spot_band + shared))
            odd[r] = _fall_distance(shares[r], wheres[r], stretch, typical) > allowed[r]
    return odd


@njit(cache=True)
def _reference_rays(valid: np.ndarray) -> np.ndarray:
    """About ``_FALL_REFERENCE_RAYS`` of the ``valid`` rays (R,), spread around the spot (indices; all of them where
    that spacing meets none)."""
    chosen = _every_nth(valid, max(int(valid.sum()) // _FALL_REFERENCE_RAYS, 1))
    return chosen if len(chosen) else np.flatnonzero(valid)


@njit(cache=True)
def _long_runs(marked: np.ndarray, judged: np.ndarray, length: int) -> np.ndarray:
    """Which ``marked`` rays (R,) lie in a run of at least ``length`` marked rays around the spot, the rays not
    ``judged`` between them skipped."""
    rays = len(marked)
    kept = np.zeros(rays, dtype=np.bool_)
    order = np.flatnonzero(judged)
    count = len(order)
    if count == 0:
        return kept
    first = 0  # a run wraps around: start after an unmarked judged ray, if any
    for j in range(count):
        if not marked[order[j]]:
            first = j + 1
            break
    run = 0
    for step in range(count + 1):
        j = (first + step) % count
        if step < count and marked[order[j]]:
            run += 1
            continue
        if run >= length:
            for back in range(1, run + 1):
                kept[order[(j - back) % count]] = True
        run = 0
    return kept


@njit(cache=True)
def _read_edges(
    pixels: np.ndarray,
    lut: np.ndarray,
    offset: np.ndarray,
    ray_angles: np.ndarray,
    radii: np.ndarray,
    steps: np.ndarray,
    full_scale: float,
    centre: np.ndarray,
    model: np.ndarray,
    light: np.ndarray,
    frame_blur: tuple[float, float],
    response: tuple[np.ndarray, np.ndarray],
) -> tuple[np.ndarray, np.ndarray, float, float, float, float, float, int, np.ndarray, float, float, float]:
    """The fine pass of :func:`detect_edge_along_rays` on rays sampled at ``steps`` (S,) around ``radii`` (R,).

    Returns each ray's edge distance from the centre (R,), whether it is valid
    (R,), the edge's width in samples, the median contrast over the noise, the
    clipped fraction of the plateau (at ``full_scale`` light or over), the median profile's plateau and
    background at the edge (linear light), and how many rays on the image
    gave no edge: no fall through the halfway level, too little contrast, a
    structure that shaped it (a plateau off its line or a dip where it falls,
    by more than ``_DARK_DIP`` of the contrast and four noises; a fall
    otherwise than the spot's light's, :func:`_misshapen_falls`), or next to
    a ray under a dark structure, and which rays were misshapen (R,).

    Where the plateau clips (over ``_REFIT_CLIPPED`` of it), each clipped
    ray's edge is the photometric model's instead
    (:func:`spotnav.image.photometry.fit_clipped_edges`): the soft band's width on
    each ray comes from the camera ``model`` and the beam's ``light``
    (:class:`spotnav.image.photometry.EdgeLight`; without them, empty, clipped rays
    are left out), the rays' origin ``centre`` in the frame, and the encoded
    frame's blur and its sigma (``frame_blur``, pixels; 0: none) under the
    ``response`` (:func:`spotnav.optics.edgeblur.response_curve`). Then the
    spot's log amplitude over full scale and blur (pixels) are returned last
    but one, and last how far its edge may lie off as a whole, pixels (1
    sigma: how well the flank pins the amplitude, times the share of the
    valid rays read from it; NaN, NaN and 0 where the plateau does not clip).
    """
    rays, count = len(ray_angles), len(steps)
    profiles, finite = _sample_rays(pixels, lut, offset, ray_angles, radii, steps)
    edge_radii = np.full(rays, np.nan)
    valid = np.zeros(rays, dtype=np.bool_)
    if not finite.any():
        return edge_radii, valid, np.nan, np.nan, 0.0, np.nan, np.nan, 0, valid.copy(), np.nan, np.nan, 0.0
    # The median profile, over about _PROFILE_RAYS lit rays, gives the edge's place and width in the window: rays
    # that vessels darken (the median of their inner half under _LIT of the brightest rays') would make it theirs,
    # and a glint on a ray hardly moves that median.
    inner = np.full(rays, np.nan)
    scratch = np.empty(max(rays, count))
    for r in range(rays):
        if finite[r]:
            inner[r] = _median(profiles[r, : count // 2], scratch)
    lit = finite & (inner >= _LIT * np.nanpercentile(inner, 90.0))
    padded, smooth_buffer = np.empty(count + len(_SMOOTHING)), np.empty(count)
    mean_smooth, mean_slope = _median_profile(profiles, lit, padded, scratch, 0, count)
    counted, measured = full_width_at_half_maximum(mean_slope)
    width = max(counted, 3.0)  # samples
    middle = int(np.argmax(mean_slope))
    lo, hi = max(int(middle - width), 0), min(int(middle + width) + 1, count - 1)
    mean_plateau = _fit_line(mean_smooth, middle - 2.5 * width, middle - 1.0 * width)
    mean_background = _fit_line(mean_smooth, middle + 1.0 * width, middle + 2.5 * width)
    quiet = _every_nth(finite, max(rays // _NOISE_RAYS, 1))
    steps_between = np.empty(len(quiet) * (count - 1))
    for j in range(len(quiet)):
        for s in range(count - 1):
            steps_between[j * (count - 1) + s] = abs(profiles[quiet[j], s + 1] - profiles[quiet[j], s])
    noise = 1.4826 * _median(steps_between, steps_between) / np.sqrt(2.0)
    contrast = np.zeros(rays)
    shares = np.empty((rays, count))  # each ray's smoothed samples between its lines (0 background, 1 plateau) ...
    fall_reach = 2.0 * measured + 2.0  # ... about its crossing, as far as a fall twice the edge's width reads
    wheres = np.zeros(rays)
    ray_backgrounds = np.zeros((rays, 2))  # each ray's background at its crossing and its slope per pixel
    # Only the samples the lines and the crossing read are smoothed.
    needed = (max(int(np.floor(middle - 2.5 * width)) - 1, 0), int(np.ceil(middle + 2.5 * width)) + 2)
    for r in range(rays):
        smooth = mean_smooth
        if finite[r]:
            smooth = _smooth(profiles[r], _SMOOTHING, needed[0], needed[1], padded, smooth_buffer)
        plateau = _fit_line(smooth, middle - 2.5 * width, middle - 1.0 * width)
        background = _fit_line(smooth, middle + 1.0 * width, middle + 2.5 * width)
        step = (plateau[0] - background[0]) + (plateau[1] - background[1]) * middle
        where, has_fall = _crossing(smooth, plateau, background, lo, hi, _HYSTERESIS * abs(step) + 2.0 * noise)
        contrast[r] = (plateau[0] - background[0]) + (plateau[1] - background[1]) * where
        valid[r] = finite[r] and has_fall and contrast[r] > max(4.0 * noise, 1e-4)
        # A plateau that is not flat where its line is fitted (either way: rejecting only the darker ones would
        # keep the brighter), or a dip where the edge falls: a structure, not the light, shaped the edge.
        allowed = _DARK_DIP * contrast[r] + 4.0 * noise
        rough = _line_deviation(smooth, plateau, middle - 2.5 * width, middle - 1.0 * width) > allowed
        if valid[r] and (rough or _deepest_dip(smooth, int(middle - 2.5 * width), int(lo), hi, scratch) > allowed):
            valid[r] = False
        edge_radii[r] = radii[r] + steps[0] + where * (steps[1] - steps[0])
        wheres[r] = where
        shares[r, :] = np.nan
        if valid[r]:
            for k in range(max(int(where - fall_reach), needed[0]), min(int(where + fall_reach) + 2, needed[1], count)):
                low = background[0] + background[1] * k
                shares[r, k] = (smooth[k] - low) / (plateau[0] + plateau[1] * k - low)
        ray_backgrounds[r, 0] = background[0] + background[1] * where
        ray_backgrounds[r, 1] = background[1] / (steps[1] - steps[0])
    plateau_samples = range(max(int(middle - 2.5 * width), 0), min(max(int(middle - width), 1), count))
    clipped_samples, samples = 0, 0
    clipped_rays = np.zeros(rays, dtype=np.bool_)  # a ray whose plateau reaches full scale has no half level
    for r in range(rays):
        if finite[r]:
            for s in plateau_samples:
                clipped_rays[r] |= profiles[r, s] >= full_scale
                clipped_samples += profiles[r, s] >= full_scale
                samples += 1
    clipped = clipped_samples / max(samples, 1)
    # Next to a ray on the image without a light's edge (a vessel or the shaft over it) the edge is the dark
    # structure's: the rays within _NEAR_DARK_WIDTHS edge widths and _NEAR_DARK_PX of it along the edge are left out.
    spacing = 2.0 * np.pi * np.mean(radii) / rays
    near = int(np.ceil((_NEAR_DARK_WIDTHS * width * (steps[1] - steps[0]) + _NEAR_DARK_PX) / spacing))
    blocked = finite & ~lit
    beside_dark = np.zeros(rays, dtype=np.bool_)
    for r in range(rays):
        if valid[r]:
            for d in range(-near, near + 1):
                if blocked[(r + d) % rays]:
                    beside_dark[r] = True
                    break
    # A ray whose fall is not the spot's light's; only where the plateau does not clip: a clipped spot's falls differ
    # by how far each ray clips, and the flank model reads them.
    misshapen = np.zeros(rays, dtype=np.bool_)
    judged = valid & ~beside_dark
    # Only on a spot whose edge is mostly read: on a short arc (the shaft over the rest) too few rays, too alike in
    # place, tell a vessel from the texture, and leaving any out shortens an arc whose bias no residual shows.
    wide = measured * (steps[1] - steps[0]) >= _MIN_FALL_PX
    if clipped <= _REFIT_CLIPPED and wide and judged.sum() >= _MIN_JUDGED * finite.sum() and judged.any():
        fall_allowed = _FALL_SHIFT_PX / (measured * (steps[1] - steps[0])) + 4.0 * noise / np.maximum(contrast, 1e-6)
        misshapen = _misshapen_falls(
            shares, wheres, fall_allowed, judged, measured * (steps[1] - steps[0]), steps[1] - steps[0], centre,
            ray_angles, edge_radii, model, light,
        )  # fmt: skip
        # Where most rays' falls differ from their median, that is no spot's fall: the texture shapes every ray, and
        # the test cannot tell a vessel along the edge from it. Else a vessel along the edge shapes a run of rays;
        # a ray alone, the texture.
        if misshapen.sum() > _MAX_MISSHAPEN * judged.sum():
            misshapen[:] = False
        misshapen = _long_runs(misshapen, judged, max(int(np.ceil(_MISSHAPEN_RUN_PX / spacing)), 2))
        valid &= ~misshapen
        rest = lit & ~misshapen
        if misshapen.any() and rest.sum() >= _PROFILE_RAYS // 4:
            # A vessel along the edge narrows the median fall too: the edge's width is the other rays'.
            # Only about the edge (the whole profile where the fall reaches that far): it is about a width wide.
            first, last = max(int(middle - 1.5 * width), 0), min(int(middle + 1.5 * width) + 2, count)
            slope = _median_profile(profiles, rest, padded, scratch, first, last)[1]
            near = slope[first + (first > 0) : last - (last < count)]
            peak = int(np.argmax(near))
            if peak in (0, len(near) - 1) or max(near[0], near[-1]) >= 0.5 * near[peak]:  # the fall reaches past it
                near = _median_profile(profiles, rest, padded, scratch, 0, count)[1]
            remeasured = full_width_at_half_maximum(near)[1]
            if np.isfinite(remeasured) and remeasured > 0.0:
                measured = remeasured
    log_amplitude, blur, shift_sigma = np.nan, np.nan, 0.0
    if clipped > _REFIT_CLIPPED and len(light) == 0:
        valid &= ~clipped_rays  # no model of the light to read a clipped ray with
    elif clipped > _REFIT_CLIPPED:
        bands = ray_bands(model, light, centre, ray_angles, edge_radii)
        read = valid & clipped_rays & np.isfinite(bands)
        if not read.any() or np.median(bands[read]) < _MIN_BAND_PX:
            valid &= ~clipped_rays  # a sharp beam blown out to a step: no flank left to read
        else:
            sample_radii = np.empty((rays, count))
            for r in range(rays):
                for s in range(count):
                    sample_radii[r, s] = radii[r] + steps[s]
            fitted, flank, log_amplitude, blur, shift_sigma = fit_clipped_edges(
                (pixels.shape[0], pixels.shape[1]), offset, ray_angles, sample_radii, profiles, edge_radii, read,
                ray_backgrounds, full_scale, bands, noise, frame_blur, response,
            )  # fmt: skip
            for r in range(rays):
                if valid[r] and clipped_rays[r]:
                    edge_radii[r] = fitted[r]
                    valid[r] = flank[r] >= _MIN_FLANK_SAMPLES and np.isfinite(fitted[r])
    valid &= ~beside_dark
    # The amplitude's uncertainty shifts only the rays read from the flank: over the whole edge, their share of it.
    shift_sigma *= np.sum(valid & clipped_rays) / max(np.sum(valid), 1)
    contrast_valid = contrast[_every_nth(valid, 1)]
    ratio = np.median(contrast_valid) / max(noise, 1e-6) if len(contrast_valid) else np.nan
    plateau_level = mean_plateau[0] + mean_plateau[1] * middle
    background_level = mean_background[0] + mean_background[1] * middle
    left_out = int(np.sum(finite & ~valid))
    return (
        edge_radii,
        valid,
        measured,
        ratio,
        clipped,
        plateau_level,
        background_level,
        left_out,
        misshapen,
        log_amplitude,
        blur,
        shift_sigma,
    )


@njit(cache=True)
def _aligned_radii(
    pixels: np.ndarray,
    lut: np.ndarray,
    offset: np.ndarray,
    ray_angles: np.ndarray,
    radii: np.ndarray,
    steps: np.ndarray,
    reach: float,
) -> np.ndarray:
    """The coarse pass of :func:`detect_edge_along_rays`: each ray's edge, within ``reach`` of ``radii`` (R,).

    Every ``_COARSE_RAY_STRIDE``-th ray is sampled at ``steps`` (S,) around
    ``radii``; its edge is the outermost fall through ``_COARSE_LEVEL`` of its
    smoothed range. The edges are median-filtered over ``_EDGE_MEDIAN_RAYS``
    neighbours around the spot and interpolated, in angle, to every ray.
    """
    coarse = np.arange(0, len(ray_angles), _COARSE_RAY_STRIDE)
    rays, count = len(coarse), len(steps)
    profiles, _ = _sample_rays(pixels, lut, offset, ray_angles[coarse], radii[coarse], steps)
    shift = np.zeros(rays)
    padded, smooth_buffer = np.empty(count + len(_SMOOTHING)), np.empty(count)
    for r in range(rays):
        for i in range(count):
            if np.isnan(profiles[r, i]):
                profiles[r, i] = 0.0  # off the image: dark
        smooth = _smooth(profiles[r], _SMOOTHING, 0, count, padded, smooth_buffer)
        low, high = smooth.min(), smooth.max()
        threshold = low + _COARSE_LEVEL * (high - low)
        for i in range(count - 2, -1, -1):
            if smooth[i] > threshold and not smooth[i + 1] > threshold:
                shift[r] = steps[i + 1]
                break
    half = _EDGE_MEDIAN_RAYS // 2
    coarse_radii, window = np.empty(rays), np.empty(_EDGE_MEDIAN_RAYS)
    for r in range(rays):
        for k in range(_EDGE_MEDIAN_RAYS):
            window[k] = shift[(r + k - half) % rays]
        coarse_radii[r] = radii[coarse[r]] + _median(window, window)  # refilled for each ray
    aligned = np.empty(len(ray_angles))
    for j in range(len(ray_angles)):
        before, after = j // _COARSE_RAY_STRIDE, (j // _COARSE_RAY_STRIDE + 1) % rays
        gap = (ray_angles[coarse[after]] - ray_angles[coarse[before]]) % (2.0 * np.pi)
        weight = (ray_angles[j] - ray_angles[coarse[before]]) % (2.0 * np.pi) / gap if gap > 0 else 0.0
        edge = (1.0 - weight) * coarse_radii[before] + weight * coarse_radii[after]
        aligned[j] = min(max(edge, radii[j] - reach), radii[j] + reach)
    return aligned


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
