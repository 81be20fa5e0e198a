"""The photometric edge: the beam's light across a spot's edge as one pixel records it, and how wide its soft band is
along each ray.

A beam's light falls off across its edge by a known shape: Blender's (and spotnav's renderer's) smoothstep over the
soft band ``2 (beta - edge)`` of the cone's angle, centred on the half-light angle that the cone fit reads
(``instrument.edge_half_angle_deg``). The camera sees it blurred (the pixels' footprint, the lens, the light's own
size): :func:`pixel_light` is the band's smoothstep averaged over a pixel's square and a small blur for the rest, in
closed form; :class:`EdgeLight` holds where the band lies (the camera and the beam's cone) and :func:`ray_bands` its
width in pixels along each ray. Where a spot clips, :mod:`spotnav.image.clipped` reads its edge with this model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from spotnav.optics.camera import camera_model, model_centre, model_optical_axis, sphere_point
from spotnav.optics.defocus import blur_scale_px
from spotnav.optics.light import edge_angle
from spotnav.setup.config import Setup

__all__ = ["EdgeLight", "edge_light", "pixel_light", "ray_light_blurs"]


_BOX_MIN_PX = 1e-3  # a box narrower than this is left out of the footprint (its differences would cancel)
# The band's ramp P (0 inside the band's inner side, 1 past its outer side: the light's fall) and its first three
# antiderivatives in the band's own unit, over the band, and their values at its outer end.
_RAMP_AT_END = (1.0, 0.5, 0.15, 1.0 / 30.0)


@njit(cache=True)
def _ramp_integral(order: int, x: float, band: float) -> float:
    """The ``order``-th antiderivative in ``x`` of the band's ramp ``P`` (-1: its derivative), zero inside the
    band's inner side. ``P = 3 y^2 - 2 y^3`` over the band, ``y = x / band + 1/2``, 0 before and 1 after it; a
    band under a billionth of a pixel is a step."""
    inner = -0.5 * band
    if band < 1e-9:
        z = x - inner
        if z <= 0.0 or order < 0:
            return 0.0
        return z**order / math.gamma(order + 1.0)
    y = (x - inner) / band
    if y <= 0.0:
        return 0.0
    if y <= 1.0:
        if order == -1:
            return 6.0 * y * (1.0 - y) / band
        if order == 0:
            return y * y * (3.0 - 2.0 * y)
        if order == 1:
            return band * y**3 * (1.0 - 0.5 * y)
        if order == 2:
            return band**2 * y**4 * (0.25 - 0.1 * y)
        return band**3 * y**5 * (1.0 / 20.0 - y / 60.0)
    if order < 0:
        return 0.0
    # Past the band: the Taylor series about its outer end, which is exact (the ramp is 1 from there on).
    past = x - inner - band
    total, term = 0.0, 1.0
    for k in range(order + 1):
        total += _RAMP_AT_END[order - k] * band ** (order - k) * term
        term *= past / (k + 1)
    return total


@njit(cache=True)
def _footprint_average(order: int, x: float, band: float, cos: float, sin: float, blur: float) -> float:
    """The ramp's ``order``-th antiderivative (0: the ramp itself, -1: its derivative) averaged over a pixel's
    footprint about ``x``: the pixel's square seen along the ray ``(cos, sin)`` is a trapezoid, two boxes
    ``|cos|`` and ``|sin|`` wide convolved, and the blur a third box of the same variance (``sqrt(12) blur``).
    Each box is a central difference of the next antiderivative over its width (a box spline)."""
    widths = (abs(cos), abs(sin), math.sqrt(12.0) * blur)
    boxes, scale = 0, 1.0
    for width in widths:
        if width >= _BOX_MIN_PX:
            boxes += 1
            scale *= width
    total = 0.0
    for corner in range(8):  # a box left out takes only its upper corner, unshifted
        shift, sign, kept = 0.0, 1.0, True
        for b in range(3):
            upper = corner >> b & 1
            if widths[b] < _BOX_MIN_PX:
                kept &= upper == 1
            elif upper:
                shift += 0.5 * widths[b]
            else:
                shift -= 0.5 * widths[b]
                sign = -sign
        if kept:
            total += sign * _ramp_integral(order + boxes, x + shift, band)
    return total / scale


@njit(cache=True)
def pixel_light(x: float, band_px: float, cos: float, sin: float, blur_px: float) -> float:
    """The beam's light as a fraction of its plateau over a pixel whose centre lies ``x`` pixels outward of the
    half-light point, along a ray in direction ``(cos, sin)``.

    The smoothstep ``3 t^2 - 2 t^3``, ``t = 1/2 - x / band_px`` clipped to
    [0, 1] (Cycles' spot blend, narrow enough to be linear in the angle),
    averaged exactly over the pixel's square and a box of the blur's variance
    (in closed form: the band's ramp is a cubic, its averages over boxes
    differences of its antiderivatives).

    Parameters
    ----------
    x : float
        Pixels outward (toward the dark background) of the half-light point.
    band_px : float
        The soft band's full width along the ray, pixels (0: a sharp beam).
    cos, sin : float
        The ray's direction in the frame.
    blur_px : float
        The blur beyond the pixel's square, pixels (its sigma).

    Returns
    -------
    float
        In [0, 1].
    """
    reach = _support(band_px, cos, sin, blur_px)
    if x >= reach:  # exactly dark or lit beyond the band and the footprint: the differences there only round
        return 0.0
    if x <= -reach:
        return 1.0
    return min(max(1.0 - _footprint_average(0, x, band_px, cos, sin, blur_px), 0.0), 1.0)


@njit(cache=True)
def _support(band: float, cos: float, sin: float, blur: float) -> float:
    """How far from the half-light point the band and a pixel's footprint (its boxes) reach, pixels."""
    return 0.5 * (band + abs(cos) + abs(sin) + math.sqrt(12.0) * blur)


@njit(cache=True)
def _pixel_light_rate(x: float, band: float, cos: float, sin: float, blur: float) -> float:
    """The rate of :func:`pixel_light` in ``x``, per pixel (never positive)."""
    if abs(x) >= _support(band, cos, sin, blur):
        return 0.0
    return -_footprint_average(-1, x, band, cos, sin, blur)


@njit(cache=True)
def _inverse_profile(level: float, band: float, blur: float, cos: float, sin: float) -> float:
    """Where a pixel's light (:func:`pixel_light`) falls to ``level`` (in (0, 1)), pixels outward of the
    half-light point."""
    low, high = -0.5 * band - 9.0 * blur - 1.0, 0.5 * band + 9.0 * blur + 1.0
    for _ in range(30):
        middle = 0.5 * (low + high)
        if pixel_light(middle, band, cos, sin, blur) > level:
            low = middle
        else:
            high = middle
    return 0.5 * (low + high)


@njit(cache=True)
def _angle_from_axis(model: np.ndarray, light: np.ndarray, u: float, v: float) -> float:
    """The angle between the beam's axis and the direction from its apex to pixel ``(u, v)``'s retina point."""
    x, y, z = sphere_point(model, u, v, light[8])
    x, y, z = x - light[0], y - light[1], z - light[2]
    cosine = (x * light[3] + y * light[4] + z * light[5]) / math.sqrt(x * x + y * y + z * z)
    return math.acos(min(max(cosine, -1.0), 1.0))


@njit(cache=True)
def ray_bands(
    model: np.ndarray, light: np.ndarray, centre: np.ndarray, angles: np.ndarray, crossings: np.ndarray
) -> np.ndarray:
    """The soft band's width along each ray, pixels: its angular width over the rate at which the ray's angle
    from the beam's axis grows at its crossing (one pixel's difference).

    ``model`` is the camera's (:func:`spotnav.optics.camera.camera_model`), ``light``
    an :class:`EdgeLight`'s array; ``centre`` (2,) the rays' origin in the
    frame, ``angles`` (R,) their directions and ``crossings`` (R,) pixels along
    them. NaN where a ray misses the bowl or its angle does not grow.
    """
    bands = np.full(len(angles), np.nan)
    for r in range(len(angles)):
        cos, sin = math.cos(angles[r]), math.sin(angles[r])
        u, v = centre[0] + crossings[r] * cos, centre[1] + crossings[r] * sin
        rate = _angle_from_axis(model, light, u + cos, v + sin) - _angle_from_axis(model, light, u, v)
        if rate > 0.0:
            bands[r] = (light[7] - light[6]) / rate
    return bands


@njit(cache=True)
def ray_light_blurs(
    model: np.ndarray, light: np.ndarray, centre: np.ndarray, angles: np.ndarray, crossings: np.ndarray
) -> np.ndarray:
    """The light's blur by the lens's depth of field at each ray's crossing (sigma, pixels,
    :func:`spotnav.optics.defocus.light_blur_px`): its retina point's depth off the focal plane.

    Arguments as :func:`ray_bands`'. Where a ray's crossing misses the bowl, the spot's centre's.
    """
    blurs = np.zeros(len(angles))
    if light[9] == 0.0:
        return blurs
    camera, axis = model_centre(model), model_optical_axis(model)
    for r in range(len(angles)):
        u, v = centre[0], centre[1]
        if np.isfinite(crossings[r]):
            u, v = u + crossings[r] * math.cos(angles[r]), v + crossings[r] * math.sin(angles[r])
        x, y, z = sphere_point(model, u, v, light[8])
        if not np.isfinite(x):
            x, y, z = sphere_point(model, centre[0], centre[1], light[8])
        depth = (x - camera[0]) * axis[0] + (y - camera[1]) * axis[1] + (z - camera[2]) * axis[2]
        if np.isfinite(depth) and depth > 0.0:
            blurs[r] = light[9] * abs(light[11] - 1.0 / depth)
    return blurs


@dataclass(frozen=True)
class EdgeLight:
    """Where a beam's soft band lies, for reading its spot where it clips: the camera and the beam's cone.

    Attributes
    ----------
    model : ndarray
        The camera's compiled model (:func:`spotnav.optics.camera.camera_model`).
    light : ndarray, shape (12,)
        The edge cone's apex (3, eye frame, mm: the tip, or behind it for a light of finite size), the beam's
        axis (3, unit), the band's inner and outer angles from the axis (radians: the edge less and plus half
        ``instrument.edge_band_deg``; by default ``2 edge - beta`` and ``beta``), the eye's radius (mm), and the
        lens's depth of field: its blur per unit of ``|1/focus - 1/depth|`` (:func:`spotnav.optics.defocus.
        blur_scale_px`, pixels mm), that blur's 1 sigma as a share of itself, and ``1/focus`` (mm^-1)
        (:func:`ray_light_blurs`).
    """

    model: np.ndarray
    light: np.ndarray


def edge_light(setup: Setup, tip_in_eye: np.ndarray, beam_axis: np.ndarray) -> EdgeLight:
    """The :class:`EdgeLight` of a beam with this axis from a tip about here (a start or a prediction will do:
    the band's width changes slowly with the pose).

    The band is the smoothstep in the light's angle over ``instrument.edge_band_deg`` centred on the edge model's
    half-light angle (:func:`spotnav.optics.light.edge_angle`); by default from ``beta`` in to ``2 edge - beta``, and
    a beam whose edge model lies at or beyond ``beta`` is sharp. The light's blur is the camera's depth of field's
    (``camera.aperture_mm``, ``camera.focus_distance_mm``), its 1 sigma from ``calibration.aperture_sigma_mm``.
    """
    instrument = setup.instrument
    edge = edge_angle(setup)
    if instrument.edge_band_deg is None:
        outer = max(instrument.beam_half_angle, edge)
    else:
        outer = edge + 0.5 * math.radians(instrument.edge_band_deg)
    axis = np.asarray(beam_axis, dtype=float)
    apex = np.asarray(tip_in_eye, dtype=float) - axis * instrument.light_radius_mm / np.tan(edge)
    camera = setup.camera
    aperture = camera.lens_aperture_mm
    share = setup.calibration.aperture_sigma_mm / aperture if aperture > 0 else 0.0
    lens = (blur_scale_px(camera), share, 1.0 / camera.focus_depth_mm)
    light = np.concatenate((apex, axis, (2.0 * edge - outer, outer, setup.eye.radius_mm), lens))
    return EdgeLight(camera_model(setup.camera), light)
