"""Spot detection as the thesis does it (section 5.3, Algorithm 1): grey conversion, median blur, Gaussian blur,
Otsu's threshold and ``findContours`` without approximation, contours of more than 5 points; optionally on a shrunk
frame (outlined again on a finer one) and with a broad background (an endo-illuminator's glow) removed first. The
regions found are :class:`Spot` s of a :class:`SpotDetection`, largest first.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from spotnav.image.channels import _shrunk_gray

__all__ = ["Spot", "SpotDetection", "detect_spots_otsu", "otsu_threshold"]


_MIN_CONTOUR_POINTS = 5
_MIN_AREA_FRACTION = 0.1  # blobs smaller than this fraction of the largest are clutter
_BACKGROUND_DISC_PX = 16  # the broad background is opened on a grid where its disc is about this wide
_MIN_CONTRAST_DN = 6.0


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
        How many bright regions were found (:func:`spotnav.image.fragments.group_fragments`); 0: not
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
        Grey, RGB or RGBA, 8 or 16 bits (see :func:`spotnav.image.channels.to_gray8`).
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
