"""The sub-pixel edge reader: a spot's edge located to a fraction of a pixel along rays across it, independently of
the light's power. It casts the rays (around a spot's Otsu contour, or through any closed curve), reads the frame
only near them (the rays are the region of interest) in one compiled call (:func:`_edge_on_rays`: the coarse and
fine passes of :mod:`spotnav.image.passes` and the encoded frame's blur of :mod:`spotnav.image.frameblur`), and
returns the edge's points with what the reading tells of them (:class:`SpotEdge`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from spotnav.image.channels import _decoding, _linear_crop
from spotnav.image.frameblur import _CURVED_MODEL, _encoded_blur
from spotnav.image.passes import _aligned_radii, _read_edges
from spotnav.image.photometry import EdgeLight
from spotnav.image.profiles import _STEP_PX
from spotnav.image.spots import Spot
from spotnav.optics.edgeblur import response_curve
from spotnav.optics.pixelnoise import new_noise_pool

__all__ = [
    "SpotEdge",
    "curve_rays",
    "detect_edge_along_rays",
    "detect_edge_subpixel",
    "edge_window_px",
    "rays_around_spot",
    "rays_through_curve",
]


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
        (:func:`spotnav.image.clipped.fit_clipped_edges`); NaN elsewhere.
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
        (:func:`spotnav.image.clipped.fit_clipped_edges`): there, the shift of
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


_NO_MODEL, _NO_LIGHT = np.zeros(0), np.zeros(0)  # no light to read a clipped spot with
_COARSE_SAMPLES = 64
_RAY_SPACING_PX = 1.0  # along the spot's outline: vessels leave short arcs of edge between them
# The frame's blur after its encoding (from its noise) beyond which the falls are not judged: at 1.5 px (384 px) the
# rays left out were those the blur shaped, and the rest gave a tip 0.13 mm off at 5 sigma; at 1 px (1024 px) the
# test still leaves out the rays a vessel shaped (88 % of 16 helix tips within 3 sigma, against 81 %).
_MAX_FALL_TEST_BLUR_PX = 1.25
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
        The frame (see :func:`spotnav.image.channels.linear_luminance`).
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
    between them (:func:`spotnav.image.profiles._crossing`). Levels relative to the local plateau and
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
        The frame (see :func:`spotnav.image.channels.linear_luminance`).
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
    code at full scale (:func:`spotnav.image.channels._decoding`); ``centre`` (2,) pixels, ``angles``
    (R,) radians, ``radii`` (R,) pixels; ``response`` the light and its
    encoded values (:func:`spotnav.optics.edgeblur.response_curve`); ``noise_pool``
    the stream's ring noise (:func:`spotnav.optics.pixelnoise.pooled_frame_blur`).
    Returns, in order: the edge points (N, 2) in pixels, the rays (N,) that gave them
    (indices), the edge's width in samples, whether any channel clipped,
    :func:`spotnav.image.passes._read_edges`' contrast to noise, clipped fraction, plateau,
    background, rays left out and misshapen, log amplitude, blur and flank shift, and
    :func:`spotnav.image.frameblur._encoded_blur`'s four values.
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
    window: float = (2.0 if align else 1.0) * (0.15 * np.mean(radii) + 8.0)
    return window
