"""The edge reader's profiles along rays, compiled: bilinear samples of the light along each ray, their smoothing,
the straight lines fitted to a plateau or a background, where a profile falls through the level halfway between
them, how deep it dips and how far it strays from a line, and the median profile of many rays.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from spotnav.image.selection import _every_nth, _median
from spotnav.optics.edgeblur import EDGE_SMOOTHING_PX

_STEP_PX = 0.5
_PROFILE_RAYS = 64  # the median profile is taken over about this many rays

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
