"""A spot's edge as the edge reader sees it: the beam's soft band, blurred in light, encoded, blurred again.

The reader (:func:`spotnav.image.rays.detect_edge_along_rays`) puts an edge
where the decoded light crosses the level halfway between plateau and
background. A blur of the light (defocus, the lens) leaves that crossing
where it was; a blur of the *encoded* frame (a codec's or a camera's
smoothing) moves it, the more the brighter the spot against its background,
because the encoding bends the light before the blur averages it. This module
models that edge (:func:`seen_edge`) and gives the blur of the encoded frame
that widens it to a measured width (:func:`frame_blur_for_width`) and the
shift of its crossing (:func:`frame_blur_shift`).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numba import njit

from spotnav.optics.response import encode_light

__all__ = [
    "EDGE_SMOOTHING_PX",
    "frame_blur_for_width",
    "frame_blur_shift",
    "full_width_at_half_maximum",
    "response_curve",
    "seen_edge",
]

EDGE_SMOOTHING_PX = 1.0  # sigma of the reader's smoothing along a ray, pixels: every measured edge is this much wider
_PIXEL_BLUR_PX = math.sqrt(1.0 / 12.0)  # sigma of a pixel's square footprint: in light, before the encoding
_SAMPLING_BLUR_PX = math.sqrt(1.0 / 6.0)  # sigma of the reader's bilinear sampling: after the decoding
_MODEL_STEP_PX = 0.05
_MODEL_SAMPLES = 50  # samples on each side of the model edge; its width and crossing are interpolated
_BISECTIONS = 10


@lru_cache(maxsize=16)
def response_curve(response: str | float) -> tuple[np.ndarray, np.ndarray]:
    """Light (0 and some 2000 steps, log-spaced down to 1e-8) and its encoded values, both strictly increasing."""
    light = np.concatenate([[0.0], np.logspace(-8.0, 0.0, 2000)])
    values = encode_light(light, response)
    knots = np.concatenate([[0], np.flatnonzero(np.diff(values) > 0) + 1])
    return light[knots], values[knots]


@njit(cache=True)
def full_width_at_half_maximum(values: np.ndarray) -> tuple[float, float]:
    """Width, in samples, of the region around the maximum above half of it: counted, and its ends interpolated.

    The count (the samples above half, the ends included) sets where the
    edge's lines are fitted; the interpolated width measures the blur.
    """
    peak = int(np.argmax(values))
    half = 0.5 * values[peak]
    left = peak
    while left > 0 and values[left - 1] > half:
        left -= 1
    right = peak
    while right < len(values) - 1 and values[right + 1] > half:
        right += 1
    width = float(right - left)
    if left > 0 and values[left] > values[left - 1]:
        width += (values[left] - half) / (values[left] - values[left - 1])
    if right < len(values) - 1 and values[right] > values[right + 1]:
        width += (values[right] - half) / (values[right] - values[right + 1])
    return float(right - left + 1), width


@njit(cache=True)
def _gaussian_nearest(values: np.ndarray, sigma: float) -> np.ndarray:
    """``values`` convolved with a Gaussian of ``sigma`` samples to 4 sigma, ends held (SciPy's ``mode="nearest"``)."""
    radius = int(4.0 * sigma + 0.5)
    kernel = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    kernel /= kernel.sum()
    count = len(values)
    out = np.empty(count)
    for i in range(count):
        total = 0.0
        for k in range(2 * radius + 1):
            total += kernel[k] * values[min(max(i + k - radius, 0), count - 1)]
        out[i] = total
    return out


@njit(cache=True)
def seen_edge(
    plateau: float, background: float, band_px: float, blur_px: float, light_grid: np.ndarray, value_grid: np.ndarray
) -> tuple[float, float]:
    """The model edge as the reader measures it: its width and where its midpoint in light lies, pixels.

    The beam's soft band (a smoothstep ``band_px`` wide from ``plateau`` to
    ``background``, linear light), averaged over the pixels' squares
    (``_PIXEL_BLUR_PX``), is encoded by the response (``light_grid`` encoded
    as ``value_grid``, :func:`response_curve`), blurred by a Gaussian of
    ``blur_px`` (sigma), decoded, and sampled and smoothed as the reader does
    (``_SAMPLING_BLUR_PX``, :data:`EDGE_SMOOTHING_PX`). Returns the full width at half maximum of its
    slope and the signed distance of its half-light crossing from the band's
    middle (outward positive; inf when there is none).
    """
    reach = 0.5 * band_px + 5.0 * (blur_px + EDGE_SMOOTHING_PX + _PIXEL_BLUR_PX + _SAMPLING_BLUR_PX) + 1.0
    step = max(_MODEL_STEP_PX, reach / _MODEL_SAMPLES)  # as many samples whatever the spot's size
    half = round(reach / step)
    x = np.arange(-half, half + 1) * step  # outward, 0 at the band's middle
    t = np.minimum(np.maximum(0.5 - x / max(band_px, step), 0.0), 1.0)
    light = _gaussian_nearest(background + (plateau - background) * t * t * (3.0 - 2.0 * t), _PIXEL_BLUR_PX / step)
    if blur_px > 0:
        encoded = _gaussian_nearest(np.interp(light, light_grid, value_grid), blur_px / step)
        light = np.interp(encoded, value_grid, light_grid)
    seen = _gaussian_nearest(light, math.hypot(_SAMPLING_BLUR_PX, EDGE_SMOOTHING_PX) / step)
    count = len(seen)
    slope = np.empty(count)  # minus np.gradient: central differences, one-sided at the ends
    slope[0], slope[-1] = seen[0] - seen[1], seen[-2] - seen[-1]
    for i in range(1, count - 1):
        slope[i] = 0.5 * (seen[i - 1] - seen[i + 1])
    width = full_width_at_half_maximum(slope)[1] * step
    level = 0.5 * (plateau + background)
    for i in range(count):
        if seen[i] <= level:
            if i == 0:
                break
            return width, x[i - 1] + step * (seen[i - 1] - level) / (seen[i - 1] - seen[i])  # between i - 1 and i
    return width, np.inf


@njit(cache=True)
def frame_blur_for_width(
    plateau: float, background: float, band_px: float, width_px: float, light_grid: np.ndarray, value_grid: np.ndarray
) -> float:
    """The blur of the encoded frame (sigma, pixels) that widens the model edge (:func:`seen_edge`) to
    ``width_px`` (bisected): 0 for an edge no wider than the unblurred model's, inf when no blur up to the width
    does."""
    if not seen_edge(plateau, background, band_px, 0.0, light_grid, value_grid)[0] < width_px:
        return 0.0
    low, high = 0.0, max(width_px, 1.0)
    if seen_edge(plateau, background, band_px, high, light_grid, value_grid)[0] < width_px:
        return np.inf
    for _ in range(_BISECTIONS):
        middle = 0.5 * (low + high)
        if seen_edge(plateau, background, band_px, middle, light_grid, value_grid)[0] < width_px:
            low = middle
        else:
            high = middle
    return high


@njit(cache=True)
def frame_blur_shift(
    plateau: float, background: float, band_px: float, blur_px: float, light_grid: np.ndarray, value_grid: np.ndarray
) -> float:
    """How far a blur of the encoded frame of ``blur_px`` (sigma) moves the edge's half-light crossing, pixels
    (outward positive: a spot brighter than its background shrinks, negative). inf for an infinite blur."""
    if not np.isfinite(blur_px):
        return -np.inf
    if blur_px <= 0.0:
        return 0.0
    blurred = seen_edge(plateau, background, band_px, blur_px, light_grid, value_grid)[1]
    return blurred - seen_edge(plateau, background, band_px, 0.0, light_grid, value_grid)[1]
