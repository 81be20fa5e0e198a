"""The edge reader's two passes over the rays, compiled: the fine pass (:func:`_read_edges`), which reads each ray's
edge where its profile falls through the level halfway between its plateau and background (or, where the plateau
clips, from the flank by the photometric model) and leaves out the rays a structure shaped; and the coarse pass
(:func:`_aligned_radii`), which first finds each ray's edge about a prediction the spot moved from.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from spotnav.image.clipped import fit_clipped_edges
from spotnav.image.falls import _long_runs, _misshapen_falls
from spotnav.image.photometry import ray_bands, ray_light_blurs
from spotnav.image.profiles import (
    _PROFILE_RAYS,
    _SMOOTHING,
    _crossing,
    _deepest_dip,
    _fit_line,
    _line_deviation,
    _median_profile,
    _sample_rays,
    _smooth,
)
from spotnav.image.selection import _every_nth, _median
from spotnav.optics.edgeblur import full_width_at_half_maximum

_REFIT_CLIPPED = 0.02  # of the plateau's samples at full scale: the half level is gone, the photometric model reads
_MIN_FLANK_SAMPLES = 1  # a clipped spot's ray needs this many samples on its unclipped flank
_MIN_BAND_PX = 1.0  # a clipped spot whose soft band is narrower has no flank beyond the pixels' own blur: left out
_COARSE_LEVEL = 0.2
_NOISE_RAYS = 32  # the noise from the steps along about this many rays (a few thousand steps)
_COARSE_RAY_STRIDE = 2
_EDGE_MEDIAN_RAYS = 5  # coarse rays, about 9 rays
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
    """The fine pass of :func:`spotnav.image.rays.detect_edge_along_rays` on rays sampled at ``steps`` (S,) around
    ``radii`` (R,).

    Returns each ray's edge distance from the centre (R,), whether it is valid
    (R,), the edge's width in samples, the median contrast over the noise, the
    clipped fraction of the plateau (at ``full_scale`` light or over), the median profile's plateau and
    background at the edge (linear light), and how many rays on the image
    gave no edge: no fall through the halfway level, too little contrast, a
    structure that shaped it (a plateau off its line or a dip where it falls,
    by more than ``_DARK_DIP`` of the contrast and four noises; a fall
    otherwise than the spot's light's, :func:`spotnav.image.falls._misshapen_falls`), or next to
    a ray under a dark structure, and which rays were misshapen (R,).

    Where the plateau clips (over ``_REFIT_CLIPPED`` of it), each clipped
    ray's edge is the photometric model's instead
    (:func:`spotnav.image.clipped.fit_clipped_edges`): the soft band's width on
    each ray comes from the camera ``model`` and the beam's ``light``
    (:class:`spotnav.image.photometry.EdgeLight`, with the light's blur by the lens; without them, empty, clipped
    rays are left out), the rays' origin ``centre`` in the frame, and the encoded
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
    valid: np.ndarray = np.zeros(rays, dtype=np.bool_)  # not NDArray[bool]: numpy's stubs sum one to a bool
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
    near_rays = int(np.ceil((_NEAR_DARK_WIDTHS * width * (steps[1] - steps[0]) + _NEAR_DARK_PX) / spacing))
    blocked = finite & ~lit
    beside_dark = np.zeros(rays, dtype=np.bool_)
    for r in range(rays):
        if valid[r]:
            for d in range(-near_rays, near_rays + 1):
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
                ray_light_blurs(model, light, centre, ray_angles, edge_radii), light[10],
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
    """The coarse pass of :func:`spotnav.image.rays.detect_edge_along_rays`: each ray's edge, within ``reach`` of
    ``radii`` (R,).

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
