"""The lens's depth of field: how far the light of a retina point off the focal plane spreads in the frame.

A thin lens of entrance pupil ``A`` (``camera.aperture_mm``) focused at depth ``S`` (``camera.focus_distance_mm``,
by default the pole's) images a point at depth ``d`` as a disk of diameter ``A f |1/S - 1/d|`` pixels, ``f`` the
focal length in pixels (the pinhole model's: the lens's image distance). A uniform disk of diameter ``c`` has the
variance of a Gaussian of sigma ``c / 4`` along each axis; that sigma is the light's blur here, as the renderer
draws it and the clipped flank's model takes it (:func:`spotnav.image.photometry.edge_light`).
"""

from __future__ import annotations

import cv2
import numpy as np

from spotnav.optics.camera import camera_depth_mm
from spotnav.setup.config import Setup
from spotnav.setup.geometry import intersect_rays_sphere
from spotnav.setup.microscope import Camera

__all__ = ["blur_scale_px", "light_blur_px", "spot_light_blur_px", "varying_blur"]

_DISK_SIGMA = 0.25  # a uniform disk's sigma along an axis, per its diameter


def light_blur_px(camera: Camera, points_in_eye: np.ndarray, aperture_mm: float | None = None) -> np.ndarray:
    """The light's blur at retina points: the sigma of a Gaussian with the variance of the lens's disk, pixels.

    Parameters
    ----------
    camera : Camera
        Its ``aperture_mm`` (0 or unstated: a pinhole, no blur), its focus depth (:attr:`Camera.focus_depth_mm`)
        and focal length in pixels.
    points_in_eye : ndarray, shape (..., 3)
        Points in the eye frame, mm.
    aperture_mm : float, optional
        The entrance pupil's diameter in place of the camera's (the blur is proportional to it: the blur per unit
        of aperture, or the blur's 1 sigma from the aperture's).

    Returns
    -------
    ndarray, shape (...)
        Sigma, pixels (0 on the focal plane).
    """
    depth = camera_depth_mm(camera, np.asarray(points_in_eye, dtype=float))
    blur: np.ndarray = blur_scale_px(camera, aperture_mm) * np.abs(1.0 / camera.focus_depth_mm - 1.0 / depth)
    return blur


def blur_scale_px(camera: Camera, aperture_mm: float | None = None) -> float:
    """The light's blur (sigma, pixels) per unit of ``|1/focus - 1/depth|`` (per mm^-1): ``A f / 4``, with the
    camera's aperture or ``aperture_mm``."""
    aperture = camera.lens_aperture_mm if aperture_mm is None else float(aperture_mm)
    return _DISK_SIGMA * aperture * camera.focal_px


def spot_light_blur_px(
    setup: Setup, tip_in_eye: np.ndarray, beam_axis: np.ndarray, aperture_mm: float | None = None
) -> float:
    """The light's blur (:func:`light_blur_px`, pixels) at a beam's spot: where its axis meets the retina.

    ``aperture_mm`` as in :func:`light_blur_px`. 0 where the axis misses the retina or the lens is a pinhole.
    """
    aperture = setup.camera.lens_aperture_mm if aperture_mm is None else float(aperture_mm)
    if aperture == 0.0:
        return 0.0
    tip, axis = np.asarray(tip_in_eye, dtype=float), np.asarray(beam_axis, dtype=float)
    reach = float(intersect_rays_sphere(tip, axis, setup.eye.center_in_eye, setup.eye.radius_mm))
    if not np.isfinite(reach):
        return 0.0
    return float(light_blur_px(setup.camera, tip + reach * axis, aperture))


_LEVEL_STEP_PX = 0.25  # the blurs a varying blur is drawn between are this far apart (sigma, pixels)


def varying_blur(linear: np.ndarray, sigma_px: np.ndarray) -> np.ndarray:
    """An image blurred by a Gaussian whose sigma varies from pixel to pixel (a depth of field), zero outside it.

    Each pixel takes the image blurred by the two sigmas on a grid ``_LEVEL_STEP_PX`` apart about its own, weighed
    so that their mixture has its own variance: where the blur varies slowly (as a retina's depth does), the
    light each pixel gathers is the lens's there.

    Parameters
    ----------
    linear : ndarray, shape (h, w, 3)
        Linear light.
    sigma_px : ndarray, shape (h, w)
        Each pixel's blur, sigma, pixels (>= 0).

    Returns
    -------
    ndarray, shape (h, w, 3)
    """
    image = np.asarray(linear, dtype=np.float32)
    top = float(np.max(sigma_px))
    count = int(np.ceil(top / _LEVEL_STEP_PX)) + 1
    levels = np.arange(count + 1) * _LEVEL_STEP_PX
    index = np.minimum((sigma_px / _LEVEL_STEP_PX).astype(int), count - 1)
    low, high = levels[index], levels[index + 1]
    weight = ((sigma_px**2 - low**2) / (high**2 - low**2)).astype(np.float32)[..., None]
    out = np.zeros_like(image)
    for k in range(count + 1):
        below, above = index == k, index + 1 == k
        if not (below.any() or above.any()):
            continue
        blurred = image if k == 0 else cv2.GaussianBlur(image, (0, 0), levels[k], borderType=cv2.BORDER_CONSTANT)
        out += np.where(below[..., None], (1.0 - weight) * blurred, 0.0)
        out += np.where(above[..., None], weight * blurred, 0.0)
    return out
