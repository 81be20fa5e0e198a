"""Pinhole camera: projection of eye-frame points and back-projection of pixels.

The camera sits at ``(0, 0, distance_mm)`` looking down ``-z``; its frame is
``x_cam = x``, ``y_cam = -y``, ``z_cam = distance_mm - z`` (contract). Pixels are
``(u, v)`` = (column, row) with centres at integer coordinates.
"""

from __future__ import annotations

import numpy as np

from spotnav.config import Camera
from spotnav.geometry import intersect_rays_sphere

__all__ = [
    "pixel_rays",
    "pixels_behind_segment",
    "project_points",
    "unproject_pixels_to_plane",
    "unproject_pixels_to_sphere",
]


def _check_last_axis(name: str, array: np.ndarray, size: int) -> np.ndarray:
    array = np.asarray(array, dtype=float)
    if array.ndim == 0 or array.shape[-1] != size:
        raise ValueError(f"{name} must have shape (..., {size}), got {array.shape}")
    return array


def project_points(camera: Camera, points_in_eye: np.ndarray) -> np.ndarray:
    """Project eye-frame points to pixel coordinates.

    Parameters
    ----------
    camera : Camera
    points_in_eye : ndarray, shape (..., 3)
        Points in mm, below the camera.

    Returns
    -------
    ndarray, shape (..., 2)
        ``(u, v)`` in pixels.
    """
    points_in_eye = _check_last_axis("points_in_eye", points_in_eye, 3)
    cx, cy = camera.principal_point_px
    depth = camera.distance_mm - points_in_eye[..., 2]
    u = cx + camera.focal_px * points_in_eye[..., 0] / depth
    v = cy - camera.focal_px * points_in_eye[..., 1] / depth
    return np.stack([u, v], axis=-1)


def pixel_rays(camera: Camera, pixels: np.ndarray) -> np.ndarray:
    """Unit directions, in the eye frame, of the rays through pixels.

    Parameters
    ----------
    camera : Camera
    pixels : ndarray, shape (..., 2)
        ``(u, v)`` in pixels.

    Returns
    -------
    ndarray, shape (..., 3)
        Unit vectors from the pinhole :attr:`Camera.center_in_eye`.
    """
    pixels = _check_last_axis("pixels", pixels, 2)
    cx, cy = camera.principal_point_px
    x = (pixels[..., 0] - cx) / camera.focal_px
    y = -(pixels[..., 1] - cy) / camera.focal_px
    scale = 1.0 / np.sqrt(x * x + y * y + 1.0)
    return np.stack([x * scale, y * scale, -scale], axis=-1)


def unproject_pixels_to_sphere(camera: Camera, pixels: np.ndarray, radius_mm: float) -> np.ndarray:
    """Back-project pixels onto the retina sphere (exact Eq. 4.1-4.5).

    Each pixel's ray meets the bowl at the far intersection with the sphere of
    radius ``radius_mm`` centred at ``(0, 0, radius_mm)``.

    Parameters
    ----------
    camera : Camera
    pixels : ndarray, shape (..., 2)
    radius_mm : float

    Returns
    -------
    ndarray, shape (..., 3)
        Points on the retina in the eye frame, NaN where the ray misses the bowl.
    """
    rays = pixel_rays(camera, pixels)
    origin = camera.center_in_eye
    center = np.array([0.0, 0.0, radius_mm])
    t = intersect_rays_sphere(origin, rays, center, radius_mm, far=True)
    points = origin + t[..., None] * rays
    points[points[..., 2] > radius_mm] = np.nan  # only the bowl exists
    return points


def unproject_pixels_to_plane(camera: Camera, pixels: np.ndarray, height_mm: float = 0.0) -> np.ndarray:
    """Back-project pixels onto the horizontal plane ``z = height_mm``.

    Parameters
    ----------
    camera : Camera
    pixels : ndarray, shape (..., 2)
    height_mm : float
        Height of the plane in the eye frame, below the camera.

    Returns
    -------
    ndarray, shape (..., 3)
        Points on the plane in the eye frame.
    """
    if height_mm >= camera.distance_mm:
        raise ValueError(f"the plane z = {height_mm:g} mm must lie below the camera ({camera.distance_mm:g} mm)")
    rays = pixel_rays(camera, pixels)
    t = (camera.distance_mm - height_mm) / -rays[..., 2]
    return camera.center_in_eye + t[..., None] * rays


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
    pixels = _check_last_axis("pixels", pixels, 2)
    start, end = np.asarray(start_in_eye, dtype=float), np.asarray(end_in_eye, dtype=float)
    # Pixels beyond the segment's image box (grown by the radius seen at the nearer end) cannot be hidden.
    ends_px = project_points(camera, np.stack([start, end]))
    reach = radius_mm * camera.focal_px / (camera.distance_mm - max(start[2], end[2])) + 1.0
    low, high = ends_px.min(axis=0) - reach, ends_px.max(axis=0) + reach
    near = np.all((pixels >= low) & (pixels <= high), axis=-1)
    if not near.any():
        return near
    rays = pixel_rays(camera, pixels)
    along = end - start
    offset = camera.center_in_eye - start
    # Closest points of the ray's line and the segment's line, the segment's clamped to its ends.
    b, c = rays @ along, float(along @ along)
    d, e = rays @ offset, float(along @ offset)
    denominator = np.maximum(c - b * b, 1e-12)
    t = np.clip((e - b * d) / denominator, 0.0, 1.0)
    s = t[..., None] * along - offset  # from the camera to the segment's point
    distance2 = np.sum(s * s, axis=-1) - np.sum(s * rays, axis=-1) ** 2
    return near & (distance2 < radius_mm**2)
