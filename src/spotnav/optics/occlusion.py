"""What the instrument's shaft hides: the pixels whose rays pass within its radius of a segment."""

from __future__ import annotations

import numpy as np
from numba import njit

from spotnav.optics.camera import (
    camera_model,
    check_last_axis,
    model_centre,
    model_optical_axis,
    pixel_ray,
    project_rows,
)
from spotnav.setup.microscope import Camera

__all__ = ["pixels_behind_segment"]


def pixels_behind_segment(
    camera: Camera, pixels: np.ndarray, start_in_eye: np.ndarray, end_in_eye: np.ndarray, radius_mm: float
) -> np.ndarray:
    """Whether each pixel's ray passes within ``radius_mm`` of a segment: the pixels a cylinder hides.

    The instrument's shaft is such a cylinder, from the tip to the insertion
    point; it lies between the camera and the retina, so every pixel whose
    ray comes that close sees the shaft.

    Parameters
    ----------
    camera : Camera
    pixels : ndarray, shape (..., 2)
        ``(u, v)``.
    start_in_eye, end_in_eye : ndarray, shape (3,)
        The segment's ends, mm.
    radius_mm : float

    Returns
    -------
    ndarray of bool, shape (...)
    """
    pixels = check_last_axis("pixels", pixels, 2)
    ends = np.array([start_in_eye, end_in_eye], dtype=float)
    rows = np.ascontiguousarray(pixels.reshape(-1, 2), dtype=float)
    hidden = _behind_segment(camera_model(camera), rows, ends, float(radius_mm), camera.focal_px)
    return hidden.reshape(pixels.shape[:-1])


@njit(cache=True)
def _behind_segment(
    model: np.ndarray, pixels: np.ndarray, ends: np.ndarray, radius: float, focal_px: float
) -> np.ndarray:
    """:func:`pixels_behind_segment` of pixels (N, 2), compiled: the segment runs between ``ends`` (2, 3)."""
    hidden = np.zeros(len(pixels), dtype=np.bool_)
    # Pixels beyond the segment's image box (grown by the radius seen at the nearer end) cannot be hidden.
    ends_px = project_rows(model, ends)
    depth = np.inf
    centre, axis = model_centre(model), model_optical_axis(model)
    for k in range(2):  # along the optical axis: the rotation's third row
        depth = min(depth, np.sum(axis * (ends[k] - centre)))
    reach = radius * focal_px / depth + 2.0
    low_u, high_u = min(ends_px[0, 0], ends_px[1, 0]) - reach, max(ends_px[0, 0], ends_px[1, 0]) + reach
    low_v, high_v = min(ends_px[0, 1], ends_px[1, 1]) - reach, max(ends_px[0, 1], ends_px[1, 1]) + reach
    along, offset = ends[1] - ends[0], centre - ends[0]
    c, e = np.sum(along * along), np.sum(along * offset)
    for n in range(len(pixels)):
        u, v = pixels[n, 0], pixels[n, 1]
        if not (low_u <= u <= high_u and low_v <= v <= high_v):
            continue
        ray = np.array(pixel_ray(model, u, v))
        # Closest points of the ray's line and the segment's line, the segment's clamped to its ends.
        b, d = np.sum(ray * along), np.sum(ray * offset)
        t = min(max((e - b * d) / max(c - b * b, 1e-12), 0.0), 1.0)
        s = t * along - offset  # from the camera to the segment's point
        hidden[n] = np.sum(s * s) - np.sum(s * ray) ** 2 < radius * radius
    return hidden
