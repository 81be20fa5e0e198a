"""The frame's noise at the pixel scale, and the blur of the encoded frame that it shows.

A camera's noise (shot, read) is added to the light before the encoding and
is white from pixel to pixel; the encoding's rounding adds white noise of
``1/12`` code squared. A blur of the *encoded* frame (a codec's or a
camera's smoothing, a Gaussian applied to the written file) averages that
noise over its width, so neighbouring pixels' noise becomes correlated. A blur
of the light (defocus, the lens) acts before the noise is added and leaves it
white. The two blurs widen an edge alike (their profiles differ by under 1 %
of the contrast), but only the blur of the encoded frame moves the edge's
half-light point, and only it correlates the noise: the noise tells which
blur acted and how wide it was.

Along a row (and a column) of the background next to a spot, the second
differences at lags 1 and 2, ``s_k = x[i-k] - 2 x[i] + x[i+k]``, have
variances ``n A_k(b) + 6 q``: ``n`` the noise's variance before the blur,
``q`` the rounding's, and, for a Gaussian blur of ``b`` pixels (sigma,
sampled at the pixels) whose noise correlates as ``rho(d)`` (about
``exp(-d^2 / (4 b^2))``), ``A_k = 6 - 8 rho(k) + 2 rho(2k)`` (6 for white
noise, both lags alike).
Their ratio gives ``b``; texture that is smooth over a few pixels adds to
both lags almost alike at the background's scale. A blur of a pixel or more
hides the noise at lag 1 in the rounding (``A_1`` is 0.5 at 1 px, 0.04 at
2 px); lags 2 to 4 still see it, and their ratios give ``b`` up to some
2.5 px, where a blurred noise grows from lag to lag as smooth texture does
(as the lag's fourth power). There the lags the ratio did not use must see
no more than the blurred noise leaves them: texture would add to them.
Where the noise is no larger than the rounding's at any lag (a camera with
little noise, or a frame smoothed so much that only the rounding is left),
or the lags disagree, the blur is not known (NaN).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "CAMERA_NOISE_BLUR_PX",
    "NOISE_POOL_FRAMES",
    "advance_noise_pool",
    "discard_noise_reading",
    "frame_blur_from_noise",
    "new_noise_pool",
    "pooled_frame_blur",
]

_ROUNDING = 1.0 / 12.0  # variance of the encoding's rounding, codes squared
# The noise must add this share of the rounding's variance at lag 1: measured on the built-in renderer's frames
# blurred by 1 px (its noise then adds 0.55 of it), the blur found is within 0.05 px; under that the rounding of a
# field that varies by less than a code is no longer the uniform 1/12.
_MIN_NOISE = 0.4
_MAX_SAMPLES = 1024  # pixels read at most (evenly spread over the ring)
_TRIM = 4.0  # differences beyond this many of their robust sigmas (a vessel's edge, a glint) are left out
_MIN_TRIM = 3.0  # ... but never those within this many codes (integer codes of a quiet frame)
_EFFECTIVE_SHARE = 1.0 / 3.0  # overlapping differences: about a third of them are independent
_WHITE_SIGMAS = 2.0  # noise whose ratio is within this many sigmas of white noise's shows no blur ...
# ... nor noise correlated no wider than a camera's own filter in light: a render's pixel filter (Blender Cycles'
# default, Blackman-Harris 1.5 px wide, correlates its noise as a blur of some 0.5 px would), a sensor's
# demosaicing. It correlates the noise but blurs the light before the encoding, which moves no edge.
CAMERA_NOISE_BLUR_PX = 0.6
_MAX_BLUR_PX = 6.0
_LAGS = 4  # second differences at lags 1 to this: 1 and 2 for blurs up to about a pixel, the last two past it
_SHORT_PAIR_MAX_PX = 1.5  # lags 2 and 4 tell a blur up to this; past it lag 2 nears the rounding: lags 3 and 4
_MAX_LONG_BLUR_PX = 2.5  # the longest lags tell a blur up to this; past it, blurred noise looks like texture
_ROUNDING_SLACK = 0.1  # the shorter lags' variance may exceed the blurred noise's by this share of the rounding
_BISECTIONS = 24  # of the blur's range: to 4e-7 px
# A stream's ring is read over this many frames, a quarter of it each (a tracked frame at 2048 px spent a tenth of
# its time reading one ring whole); four, to tile the ring's grid.
NOISE_POOL_FRAMES = 4
_POOL_CHANNELS = 4  # the channels a pool holds (RGBA)
_WHOLE_RING = NOISE_POOL_FRAMES + 1  # a pool's mark of a frame that read the whole ring


@njit(cache=True)
def _correlation(blur_px: float, lag: int) -> float:
    """The correlation at ``lag`` pixels of white noise blurred by a Gaussian of ``blur_px`` (sigma) sampled at the
    pixels, as filters do (``exp(-lag^2 / (4 blur^2))`` for a wide one)."""
    reach = math.ceil(4.0 * blur_px) + 1
    total, shifted = 0.0, 0.0
    for i in range(-reach, reach + 1):
        weight = math.exp(-0.5 * (i / blur_px) ** 2)
        total += weight * weight
        shifted += weight * math.exp(-0.5 * ((i + lag) / blur_px) ** 2)
    return shifted / total


@njit(cache=True)
def _lag_weights(blur_px: float, lag: int) -> float:
    """``A_lag``: the variance of a second difference at ``lag`` of unit noise blurred by ``blur_px`` (sigma)."""
    if blur_px <= 0.0:
        return 6.0
    return 6.0 - 8.0 * _correlation(blur_px, lag) + 2.0 * _correlation(blur_px, 2 * lag)


@njit(cache=True)
def _ratio(blur_px: float, lags: tuple[int, int]) -> float:
    """``A_lags[1] / A_lags[0]`` (:func:`_lag_weights`), the blur's weights computed once for the four
    correlations (the same sums, term by term)."""
    if blur_px <= 0.0:
        return 1.0
    reach = math.ceil(4.0 * blur_px) + 1
    longest = 2 * max(lags[0], lags[1])
    weights = np.empty(2 * reach + 1 + longest)  # weights[reach + i]: the Gaussian's at i, from -reach
    for i in range(-reach, reach + 1 + longest):
        weights[reach + i] = math.exp(-0.5 * (i / blur_px) ** 2)
    total = 0.0
    for i in range(2 * reach + 1):
        total += weights[i] * weights[i]
    lag_weights = np.empty(2)
    for j in range(2):
        once = twice = 0.0  # the correlations at the lag and at twice it, times total
        for i in range(2 * reach + 1):
            once += weights[i] * weights[i + lags[j]]
            twice += weights[i] * weights[i + 2 * lags[j]]
        lag_weights[j] = 6.0 - 8.0 * once / total + 2.0 * twice / total
    ratio: float = lag_weights[1] / lag_weights[0]
    return ratio


@njit(cache=True)
def _blur_of_ratio(ratio: float, lags: tuple[int, int] = (1, 2)) -> float:
    """The blur whose variance at the longer of ``lags`` over that at the shorter is ``ratio`` (bisected; 0 at or
    under 1, the largest past it)."""
    if ratio <= 1.0:
        return 0.0
    low, high = 0.0, _MAX_BLUR_PX
    if _ratio(high, lags) <= ratio:
        return high
    for _ in range(_BISECTIONS):
        middle = 0.5 * (low + high)
        if _ratio(middle, lags) < ratio:
            low = middle
        else:
            high = middle
    return 0.5 * (low + high)


@njit(cache=True)
def _trimmed_variance(values: np.ndarray) -> float:
    """The variance (about 0) of ``values`` with their outliers left out (iterated)."""
    if len(values) == 0:
        return np.nan
    variance: float = np.mean(values * values)
    kept = len(values)
    for _ in range(3):
        limit = max(_TRIM * math.sqrt(variance), _MIN_TRIM)
        total, count = 0.0, 0
        for value in values:
            if abs(value) <= limit:
                total += value * value
                count += 1
        variance = total / max(count, 1)
        if count == kept:  # the values within a limit: as many, the same ones, and the same variance again
            break
        kept = count
    return variance


@njit(cache=True)
def frame_blur_from_noise(
    codes: np.ndarray, centre: np.ndarray, inner_px: float, outer_px: float, ceiling: int
) -> tuple[float, float]:
    """The blur of the encoded frame that the noise shows in a ring about a spot, and its 1-sigma, pixels.

    Parameters
    ----------
    codes : ndarray, shape (H, W)
        One channel's codes (integers) about the spot.
    centre : ndarray, shape (2,)
        The spot's centre ``(u, v)`` in ``codes``' pixels.
    inner_px, outer_px : float
        The ring read: pixels whose centre lies this far from ``centre`` (outside the spot's edge).
    ceiling : int
        Differences that reach this code (the light of another spot, a glint, full scale) or code 0 are left
        out: only the background's noise is read.

    Returns
    -------
    blur_px, sigma_px : float
        The Gaussian blur (sigma, pixels) of the encoded frame and its uncertainty: 0 for noise as white as
        it can tell (within ``_WHITE_SIGMAS``) or no more correlated than a camera's own
        (:data:`CAMERA_NOISE_BLUR_PX`), with the blur its 1-sigma upper end would show as the sigma; NaN
        and NaN where the noise is no larger than the rounding's (``_MIN_NOISE``) at any lag, where the lags
        disagree with a blurred noise (texture), or where the ring is off the frame.
    """
    variances, count = _ring_variances(codes, centre, inner_px, outer_px, ceiling, _MAX_SAMPLES, _WHOLE_RING)
    return _blur_of_variances(variances, count)


def new_noise_pool(frames: int = NOISE_POOL_FRAMES) -> np.ndarray:
    """An empty pool of the noise beside a spot over a stream's last ``frames`` frames (:func:`pooled_frame_blur`).

    Parameters
    ----------
    frames : int
        :data:`NOISE_POOL_FRAMES` (each frame reads a quarter of the ring), or 1 (each reads it whole).

    Returns
    -------
    ndarray, shape (4, frames, 6)
        Per channel (RGBA) and frame, the newest first: which part of the ring it read (0: none; 1 to 4: a
        quarter; 5: all of it), how many differences that gave, and their variances at lags 1 to 4.

    Raises
    ------
    ValueError
        If ``frames`` is neither.
    """
    if frames not in (1, NOISE_POOL_FRAMES):
        raise ValueError(f"frames must be 1 or {NOISE_POOL_FRAMES}, got {frames}")
    return np.zeros((_POOL_CHANNELS, frames, 2 + _LAGS))


def advance_noise_pool(pool: np.ndarray) -> None:
    """Make room in ``pool`` (:func:`new_noise_pool`) for a new frame's reading: its oldest frame's leaves."""
    pool[:, 1:] = pool[:, :-1]
    pool[:, 0] = 0.0


def discard_noise_reading(pool: np.ndarray) -> None:
    """Leave the newest frame's reading out of ``pool``: the ring was read about a spot the frame did not hold."""
    pool[:, 0] = 0.0


@njit(cache=True)
def pooled_frame_blur(
    codes: np.ndarray,
    channel: int,
    centre: np.ndarray,
    inner_px: float,
    outer_px: float,
    ceiling: int,
    pool: np.ndarray,
) -> tuple[float, float]:
    """:func:`frame_blur_from_noise` from this frame's ring and the last frames' in ``pool``.

    A stream's encoding blurs every frame alike, so the noise of its last
    frames tells the blur together. The pixels :func:`frame_blur_from_noise`
    reads lie on a grid; a pool of :data:`NOISE_POOL_FRAMES` frames has each
    frame read one of the grid's four quarters (every other row and column,
    at one of four offsets) in turn, so that its last four frames read the
    whole grid once; a frame after none read reads it whole.

    Parameters
    ----------
    codes, centre, inner_px, outer_px, ceiling
        As :func:`frame_blur_from_noise`.
    channel : int
        ``codes``' channel in the frame: each channel has its own pool (one
        past the pool's four is read whole, alone).
    pool : ndarray, shape (4, frames, 6)
        :func:`new_noise_pool`, advanced once for each new frame
        (:func:`advance_noise_pool`). This frame's reading goes in its newest
        row (replacing what an earlier reading of the same frame put there).

    Returns
    -------
    blur_px, sigma_px : float
        As :func:`frame_blur_from_noise`, from every difference in the pool; a pool of one frame gives its answer.
    """
    if channel >= pool.shape[0]:
        return frame_blur_from_noise(codes, centre, inner_px, outer_px, ceiling)
    rows = pool[channel]
    part = _WHOLE_RING  # after none read (or in a pool of one frame), the whole ring
    for k in range(1, rows.shape[0]):
        if rows[k, 0] != 0.0:  # the quarter after the latest reading's (the first after a whole one)
            part = 1 if rows[k, 0] == _WHOLE_RING else int(rows[k, 0]) % NOISE_POOL_FRAMES + 1
            break
    variances, count = _ring_variances(codes, centre, inner_px, outer_px, ceiling, _MAX_SAMPLES, part)
    rows[0, 0], rows[0, 1] = part, count
    for lag in range(_LAGS):
        rows[0, 2 + lag] = variances[lag] if count > 0 else 0.0
    total = 0.0
    for k in range(rows.shape[0]):
        total += rows[k, 1]
    if total == count:  # this frame's alone: its own variances, to the last digit
        return _blur_of_variances(variances, count)
    pooled = np.zeros(_LAGS)  # the variances over all the pool's differences
    for k in range(rows.shape[0]):
        for lag in range(_LAGS):
            pooled[lag] += rows[k, 1] * rows[k, 2 + lag] / total
    return _blur_of_variances(pooled, int(total))


@njit(cache=True)
def _ring_variances(
    codes: np.ndarray, centre: np.ndarray, inner_px: float, outer_px: float, ceiling: int, samples: int, part: int
) -> tuple[np.ndarray, int]:
    """The variances (_LAGS,) of the second differences at lags 1 to ``_LAGS`` over a grid of about ``samples``
    pixels of the ring (:func:`frame_blur_from_noise`), or over one of its quarters (``part`` 1 to 4; all of it:
    ``_WHOLE_RING``), trimmed of outliers, and how many differences (two a pixel) gave them."""
    height, width = codes.shape
    ring = math.pi * (outer_px**2 - inner_px**2)
    stride = max(int(math.sqrt(ring / samples)), 1)
    size = 2 * int(ring / stride**2 + 4.0 * outer_px / stride + 8)
    shift_u = shift_v = 0  # a quarter: every other row and column of the grid, from one of four offsets
    if part != _WHOLE_RING:
        shift_u, shift_v = stride * ((part - 1) % 2), stride * ((part - 1) // 2)
        stride *= 2
    differences = np.empty((_LAGS, size))  # second differences at lags 1 to _LAGS
    count = 0
    taps = np.empty(2 * _LAGS + 1)
    first_v, last_v = max(int(centre[1] - outer_px), _LAGS), min(int(centre[1] + outer_px) + 1, height - _LAGS)
    for v in range(first_v + shift_v, last_v, stride):
        across = v - centre[1]
        if abs(across) > outer_px:
            continue
        reach = math.sqrt(outer_px**2 - across**2)
        gap = math.sqrt(inner_px**2 - across**2) if abs(across) < inner_px else -1.0
        first_u, last_u = max(int(centre[0] - reach), _LAGS), min(int(centre[0] + reach) + 1, width - _LAGS)
        for u in range(first_u + shift_u, last_u, stride):
            if abs(u - centre[0]) < gap or count + 2 > size:
                continue
            for du, dv in ((1, 0), (0, 1)):
                usable = True
                for k in range(-_LAGS, _LAGS + 1):
                    code = codes[v + k * dv, u + k * du]
                    usable &= 0 < code < ceiling
                    taps[k + _LAGS] = code
                if usable:
                    for lag in range(1, _LAGS + 1):
                        differences[lag - 1, count] = taps[_LAGS - lag] - 2.0 * taps[_LAGS] + taps[_LAGS + lag]
                    count += 1
    variances = np.empty(_LAGS)
    for lag in range(_LAGS):
        variances[lag] = _trimmed_variance(differences[lag, :count])
    return variances, count


@njit(cache=True)
def _blur_of_variances(variances: np.ndarray, count: int) -> tuple[float, float]:
    """:func:`frame_blur_from_noise`'s answer from the ring's variances (_LAGS,) of ``count`` differences."""
    if count < 64:
        return np.nan, np.nan
    rounding = 6.0 * _ROUNDING
    independent = _EFFECTIVE_SHARE * count
    if variances[0] - rounding > _MIN_NOISE * rounding:
        ratio, spread = _lag_ratio(variances, (1, 2), independent)
        upper = _blur_of_ratio(ratio + spread)
        if ratio - _WHITE_SIGMAS * spread <= _ratio(CAMERA_NOISE_BLUR_PX, (1, 2)):  # the ratio grows with the blur
            return 0.0, upper  # the camera's own, or as white as the noise can tell: none, up to its 1-sigma upper end
        return _blur_of_ratio(ratio), 0.5 * (upper - _blur_of_ratio(ratio - spread))
    # The noise is lost in the rounding at lag 1: a blur of the encoded frame of a pixel or more (or a camera with
    # little noise). The longer lags still see a blurred noise, whose variance grows from lag to lag as the blur
    # says; smooth texture's grows as the lag's fourth power, which a blur's shows only past _MAX_LONG_BLUR_PX.
    if not variances[_LAGS - 2] - rounding > _MIN_NOISE * rounding:
        return np.nan, np.nan
    lags = (2, _LAGS)
    short_pair = variances[1] - rounding > _MIN_NOISE * rounding  # else lag 2's noise is the rounding's (or 0)
    if short_pair:
        ratio, spread = _lag_ratio(variances, lags, independent)
        short_pair = _blur_of_ratio(ratio, lags) <= _SHORT_PAIR_MAX_PX
    if not short_pair:
        # A blur that leaves lag 2 too near the rounding: the two longest lags.
        lags = (_LAGS - 1, _LAGS)
        ratio, spread = _lag_ratio(variances, lags, independent)
    blur = _blur_of_ratio(ratio, lags)
    if ratio - _WHITE_SIGMAS * spread <= _ratio(CAMERA_NOISE_BLUR_PX, lags) or blur > _MAX_LONG_BLUR_PX:
        return np.nan, np.nan  # white at long lags but not at lag 1, or texture: not a blurred noise
    # The other lags must not see more than the blurred noise leaves them (texture would add to them); they may see
    # less: a field smoother than a code from pixel to pixel rounds to less than the uniform rounding.
    level = (variances[lags[1] - 1] - rounding) / _lag_weights(blur, lags[1])
    for lag in range(1, _LAGS):
        allowed = 3.0 * variances[lag - 1] * math.sqrt(2.0 / independent) + _ROUNDING_SLACK * rounding
        if lag not in lags and variances[lag - 1] - rounding - level * _lag_weights(blur, lag) > allowed:
            return np.nan, np.nan
    upper, lower = _blur_of_ratio(ratio + spread, lags), _blur_of_ratio(ratio - spread, lags)
    return blur, 0.5 * (upper - lower)


@njit(cache=True)
def _lag_ratio(variances: np.ndarray, lags: tuple[int, int], independent: float) -> tuple[float, float]:
    """The ratio of the noise's variances at ``lags`` (the rounding's taken out) and its 1-sigma spread: a variance
    from m independent differences is uncertain by sqrt(2 / m) of itself."""
    rounding = 6.0 * _ROUNDING
    short, long = variances[lags[0] - 1], variances[lags[1] - 1]
    ratio = max(long - rounding, 0.0) / (short - rounding)
    spread = ratio * math.sqrt(
        2.0 / independent * ((short / (short - rounding)) ** 2 + (long / max(long - rounding, rounding)) ** 2)
    )
    return ratio, spread
