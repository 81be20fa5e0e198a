"""The expected frame near the spots and what each pixel tells of it: the photometric model, for the bound and the fit.

A frame's pixel ``p`` in channel ``c`` holds the light

    x = b + a * g * E(p; pose, power),

``b`` the ambient-lit background, ``a`` the retina's albedo, ``g`` the exposure's gain
(:func:`~spotnav.optics.render.exposure_gain`) and ``E`` the irradiance of the beams averaged over the pixel
(:func:`~spotnav.optics.render.irradiance_at`; the pixels that a cone's edge crosses are supersampled as the
renderer does, :func:`~spotnav.optics.render.edge_pixels`), blurred by
the lens's defocus (``faults.defocus_px``) before the sensor adds its noise. The sensor adds Gaussian noise of
variance ``s^2 = x / N + (r / N)^2`` (shot noise of ``N = render.full_well_e`` electrons at full scale, read
noise of ``r`` electrons), clips at full scale and encodes by the response ``f`` in ``2^bits - 1`` codes,
rounding to the code (variance ``1/12`` code^2).

What the pixel tells of a parameter ``t`` of the pose is its Fisher information (docs/methods.md, "The bound")

    I_p = P(x + n < 1) * (f'(x) dx/dt)^2 / (f'(x)^2 s^2 + 1/12),

the clip keeping only the share of the noise that stays under full scale. This is the same renderer's model,
written once: :class:`~spotnav.optics.render.Renderer` draws frames from it, :mod:`spotnav.pose.bound` inverts
its information and :mod:`spotnav.pose.model_fit` fits it to a frame.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np
from scipy.special import ndtr

from spotnav.optics.render import Renderer, albedo_in_box, edge_pixels, exposure_gain, irradiance_at, noise_sigma
from spotnav.optics.response import encode_light
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose, beam_axes

__all__ = ["FrameModel", "PixelInformation", "code_information", "expected_codes"]

_MARGIN_PX = 6  # pixels around the spots' box, for the edge's blur
_SLOPE_STEP = 1e-5  # linear light: the response's slope by central differences
_NODES, _WEIGHTS = np.polynomial.hermite_e.hermegauss(7)  # Gauss-Hermite, for means over the sensor's noise
_NOISE_NODES = (_NODES, _WEIGHTS / _WEIGHTS.sum())  # the standard normal's: weights summing to 1


class FrameModel:
    """The expected linear light in a box of pixels around one pose's spots, fast to evaluate near that pose.

    The retina's points and normals under every sample are computed once; each evaluation moves only the
    light. The box and the supersampled pixels are fixed at ``pose``, so that evaluations at nearby poses
    differ smoothly (finite differences).

    Parameters
    ----------
    setup : Setup
        The world: camera, retina, light, render settings (noise, response) and ``faults.defocus_px``.
    pose : InstrumentPose
        The pose the model is built around, eye frame.

    Attributes
    ----------
    box : tuple of int or None
        ``(u0, v0, u1, v1)``, exclusive ends; ``None`` when no light reaches the visible retina.
    """

    def __init__(self, setup: Setup, pose: InstrumentPose) -> None:
        self.setup = setup
        renderer = Renderer(setup)
        camera, instrument, cfg = setup.camera, setup.instrument, setup.render
        axes = beam_axes(pose.axis, instrument.beam_count, instrument.beam_tilt)
        spots = renderer.spot_box(pose.tip_in_eye, axes)
        self.box: tuple[int, int, int, int] | None = None
        if spots is None:
            return
        margin = _MARGIN_PX + math.ceil(4.0 * setup.faults.defocus_px)
        u0, v0 = max(spots[0] - margin, 0), max(spots[1] - margin, 0)
        u1, v1 = min(spots[2] + margin, camera.width_px), min(spots[3] + margin, camera.height_px)
        self.box = (u0, v0, u1, v1)
        albedo = albedo_in_box(camera, setup.true_radius_mm, setup.world.surface, cfg, self.box)
        self._albedo = albedo.astype(float)
        self._background = (albedo * np.float32(cfg.ambient)).astype(float)  # as the renderer's, in float32
        self._gain = exposure_gain(cfg.exposure_stops)
        u, v = np.meshgrid(np.arange(u0, u1, dtype=float), np.arange(v0, v1, dtype=float))
        self._points, self._normals = renderer.surface_points(u, v, setup.world.bumps)
        _, cosines = irradiance_at(
            self._points, self._normals, pose.tip_in_eye, axes, 1.0, instrument.beam_half_angle, setup.light.blend
        )
        self._edge = edge_pixels(cosines, instrument.beam_half_angle)
        n = cfg.supersampling
        offsets = (np.arange(n) + 0.5) / n - 0.5
        du, dv = (o.ravel() for o in np.meshgrid(offsets, offsets))
        self._sub_points, self._sub_normals = renderer.surface_points(
            u[self._edge][:, None] + du, v[self._edge][:, None] + dv, setup.world.bumps
        )

    @property
    def shape(self) -> tuple[int, int, int]:
        """The box's ``(height, width, 3)``."""
        if self.box is None:
            return (0, 0, 3)
        u0, v0, u1, v1 = self.box
        return (v1 - v0, u1 - u0, 3)

    @property
    def background(self) -> np.ndarray:
        """The ambient-lit background's linear light in the box, (h, w, 3)."""
        return self._background

    def light(self, tip_in_eye: np.ndarray, beam_axes_in_eye: np.ndarray, power_w: float) -> np.ndarray:
        """The spots' linear light (full scale 1) in the box, without the background, shape (h, w, 3).

        Parameters
        ----------
        tip_in_eye : ndarray, shape (3,)
            The cones' apex, mm.
        beam_axes_in_eye : ndarray, shape (beams, 3)
            Unit beam axes.
        power_w : float
            Each beam's power, W.
        """
        half_angle, blend = self.setup.instrument.beam_half_angle, self.setup.light.blend
        irradiance, _ = irradiance_at(
            self._points, self._normals, tip_in_eye, beam_axes_in_eye, power_w, half_angle, blend
        )
        sub, _ = irradiance_at(
            self._sub_points, self._sub_normals, tip_in_eye, beam_axes_in_eye, power_w, half_angle, blend
        )
        irradiance[self._edge] = sub.mean(axis=1)
        light: np.ndarray = self._albedo * (self._gain * irradiance)[..., None]
        defocus = self.setup.faults.defocus_px
        if defocus > 0:  # the lens blurs the light before the sensor's noise
            light = np.asarray(cv2.GaussianBlur(light, (0, 0), defocus, borderType=cv2.BORDER_CONSTANT), dtype=float)
        return light


def _full_scale_codes(setup: Setup) -> float:
    return float(2**setup.render.bit_depth - 1)


def _response(setup: Setup) -> str | float:
    return setup.camera.pixel_response if setup.render.tone == "camera" else "agx"


def expected_codes(setup: Setup, linear: np.ndarray) -> np.ndarray:
    """The mean pixel value (codes, before rounding) of the light ``linear``: ``E[Q f(clip(x + n))]``.

    The mean over the sensor's noise, by Gauss-Hermite quadrature: a curved response moves it from ``Q f(x)`` by
    about ``Q f''(x) s^2 / 2`` (a third of the bound's sigma in the tip, for sRGB frames), and the clip pulls it
    under full scale near the clip.
    """
    response = _response(setup)
    sigma = noise_sigma(linear, setup.render.full_well_e, setup.render.read_noise_e).astype(float)
    mean = np.zeros_like(linear, dtype=float)
    for node, weight in zip(*_NOISE_NODES, strict=True):
        mean += weight * encode_light(np.clip(linear + node * sigma, 0.0, 1.0), response)
    return _full_scale_codes(setup) * mean


class PixelInformation(NamedTuple):
    """What each pixel's value tells of the light (:func:`code_information`); every array shaped as the light.

    Attributes
    ----------
    noise_weight : ndarray
        ``1 / (f'^2 s^2 + 1/12)``, per code^2: the pixel's weight were it never clipped.
    slope : ndarray
        ``f'(x)``, codes per unit of linear light.
    unclipped : ndarray
        ``P(x + n < 1)``, the share of the noise that stays under full scale.
    """

    noise_weight: np.ndarray
    slope: np.ndarray
    unclipped: np.ndarray

    @property
    def weight(self) -> np.ndarray:
        """``P(x + n < 1) / (f'^2 s^2 + 1/12)``: the information of a parameter ``t`` is ``weight * (slope *
        dx/dt)^2`` summed over the pixels (module docstring)."""
        weight: np.ndarray = self.noise_weight * self.unclipped
        return weight


def code_information(setup: Setup, linear: np.ndarray) -> PixelInformation:
    """What each pixel's value tells of the linear light ``linear`` it holds (module docstring)."""
    cfg = setup.render
    sigma = noise_sigma(linear, cfg.full_well_e, cfg.read_noise_e).astype(float)
    low = np.clip(linear - _SLOPE_STEP, 0.0, 1.0 - 2.0 * _SLOPE_STEP)
    response = _response(setup)
    slope = (
        _full_scale_codes(setup)
        * (encode_light(low + 2.0 * _SLOPE_STEP, response) - encode_light(low, response))
        / (2.0 * _SLOPE_STEP)
    )
    if cfg.full_well_e > 0:
        with np.errstate(divide="ignore"):  # no noise in the dark without read noise: all of it under the clip
            unclipped = ndtr((1.0 - linear) / sigma)
    else:
        unclipped = (linear < 1.0).astype(float)
    return PixelInformation(1.0 / (slope**2 * sigma**2 + 1.0 / 12.0), slope, unclipped)
