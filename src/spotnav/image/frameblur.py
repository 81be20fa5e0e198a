"""The blur of the encoded frame about a spot, which the noise in a ring beside it shows, and the shift that blur gave
the edge's half-light crossing (:func:`_encoded_blur`): the edge reader takes that shift out of its points, and a
clipped spot's flank is read again with the blur in its model.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from spotnav.image.falls import _reference_rays
from spotnav.image.photometry import ray_bands
from spotnav.optics.edgeblur import frame_blur_for_width, frame_blur_shift, seen_edge
from spotnav.optics.pixelnoise import pooled_frame_blur

_NOISE_GAP_WIDTHS = 2.5  # the noise is read from this many edge widths past the edge (the background's lines) ...
_NOISE_RING_PX = 12.0  # ... over a ring this wide, below this share of the way from background to plateau:
_NOISE_LIT = 0.25
_FRAME_SHIFT_MODEL = 0.15  # how far the edge model's shift may be off, of itself
_CURVED_MODEL = 0.25  # how far a blurred curve's shift may be off, of itself (an ellipse's curvature varies)
# A blur the noise tells this uncertainly (1 sigma) is read in the other channels too: on a dark fundus, a 2 px blur
# left the spot's channel's estimate 0.4-0.6 px uncertain.
_UNCERTAIN_BLUR_PX = 0.2


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
    background; linear light) and the beam's band on some of the ``valid`` rays
    (:func:`spotnav.image.falls._reference_rays`)
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
