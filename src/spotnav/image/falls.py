"""Which rays' falls differ from the spot's light's: each ray's fall across the edge, aligned on its crossing, against
the median fall of the spot's rays (allowing for the wider fall the geometry gives a ray), and the misshapen rays
that lie in runs around the spot (a vessel along the edge), not alone (the texture).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from spotnav.image.photometry import ray_bands
from spotnav.image.profiles import _PROFILE_RAYS
from spotnav.image.selection import _every_nth, _median
from spotnav.optics.edgeblur import EDGE_SMOOTHING_PX

_FALL_REFERENCE_RAYS = 16  # the spot's soft band from about this many rays


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
