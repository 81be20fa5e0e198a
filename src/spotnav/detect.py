"""Spot detection as in the thesis (section 5.3, Algorithm 1).

Grey conversion, median blur, Gaussian blur, Otsu threshold and
``findContours`` without approximation; contours of more than 5 points.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["Spot", "SpotDetection", "detect_spots_otsu", "to_gray8"]

_MIN_CONTOUR_POINTS = 5
_MIN_AREA_FRACTION = 0.1  # blobs smaller than this fraction of the largest are clutter
_MIN_CONTRAST_DN = 6.0
_MIN_CONTRAST_SIGMA = 6.0


@dataclass(frozen=True)
class Spot:
    """One bright region.

    Attributes
    ----------
    contour_px : ndarray, shape (N, 2)
        Boundary pixels ``(u, v)``, as ``findContours`` returns them.
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
    """

    spots: tuple[Spot, ...]
    threshold: float
    contrast: float


def to_gray8(image: np.ndarray) -> np.ndarray:
    """8-bit grey image from grey, RGB or RGBA, 8 or 16 bits.

    Parameters
    ----------
    image : ndarray, shape (H, W), (H, W, 3) or (H, W, 4), uint8 or uint16
        Colour images are RGB(A).

    Returns
    -------
    ndarray, shape (H, W), uint8

    Raises
    ------
    ValueError
        For any other shape or dtype.
    """
    if image.dtype == np.uint16:
        image = (image.astype(np.float32) * (255.0 / 65535.0) + 0.5).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise ValueError(f"image must be 8-bit or 16-bit, got {image.dtype}")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_RGBA2GRAY)
    raise ValueError(f"image must be grey, RGB or RGBA, got shape {image.shape}")


def _histogram_median(histogram: np.ndarray) -> int:
    """Median level of a histogram of integer levels (the lower one on a tie)."""
    cumulative = np.cumsum(histogram)
    return int(np.searchsorted(cumulative, 0.5 * cumulative[-1]))


def detect_spots_otsu(image: np.ndarray, blur_px: int = 5) -> SpotDetection:
    """Find the bright spots as the thesis does.

    Parameters
    ----------
    image : ndarray
        Grey, RGB or RGBA, 8 or 16 bits (see :func:`to_gray8`).
    blur_px : int
        Odd kernel size of the median and Gaussian blurs.

    Returns
    -------
    SpotDetection
    """
    gray = to_gray8(image)
    blurred = cv2.GaussianBlur(cv2.medianBlur(gray, blur_px), (blur_px, blur_px), 0)
    threshold, binary = cv2.threshold(blurred, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    contours = [c.reshape(-1, 2) for c in contours if len(c) > _MIN_CONTOUR_POINTS]
    if not contours:
        return SpotDetection((), float(threshold), 0.0)
    areas = np.array([cv2.contourArea(c) for c in contours])
    largest = int(np.argmax(areas))
    mask = np.zeros_like(binary)
    cv2.drawContours(mask, contours, largest, 255, thickness=cv2.FILLED)
    histogram = cv2.calcHist([blurred], [0], cv2.bitwise_not(binary), [256], [0, 256]).ravel()
    median = _histogram_median(histogram)
    levels = np.arange(256)
    deviations = np.bincount(np.abs(levels - median), weights=histogram, minlength=256)
    spread = 1.4826 * _histogram_median(deviations)
    contrast = float(cv2.mean(blurred, mask)[0] - median)
    min_area = max(20.0, 1e-5 * gray.size)
    if areas[largest] < min_area or contrast < max(_MIN_CONTRAST_DN, _MIN_CONTRAST_SIGMA * spread):
        return SpotDetection((), float(threshold), contrast)
    height, width = gray.shape
    order = np.argsort(-areas)
    spots = tuple(
        Spot(
            contour_px=contours[i].astype(float),
            area_px=float(areas[i]),
            touches_border=bool(
                np.any(contours[i] == 0)
                or np.any(contours[i][:, 0] == width - 1)
                or np.any(contours[i][:, 1] == height - 1)
            ),
        )
        for i in order
        if areas[i] >= _MIN_AREA_FRACTION * areas[largest]
    )
    return SpotDetection(spots, float(threshold), contrast)
