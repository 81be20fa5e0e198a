"""The camera model: OpenCV's pinhole with lens distortion and a pose, written once.

A :class:`~spotnav.setup.microscope.Camera` is the thesis's ideal pinhole above the pole
or a calibrated camera (contract); both become OpenCV's ``K``, distortion and
pose ``x_cam = R x_eye + t``. Points project as ``cv2.projectPoints`` projects
them (all 14 distortion coefficients, the tilted sensor included); pixels
back-project by inverting that model with Newton's method. Pixels are
``(u, v)`` = (column, row) with centres at integer coordinates.

The compiled kernels work on :func:`camera_model`, a flat array that every
method (the renderer, the thesis's method, the cone fit, tracking) passes to
the same functions: :func:`project_point`, :func:`pixel_ray` and
:func:`sphere_point`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit

from spotnav.setup.microscope import Camera

__all__ = [
    "CHANGE_SIZE",
    "MODEL_SIZE",
    "camera_depth_mm",
    "camera_model",
    "camera_of_model",
    "check_last_axis",
    "model_centre",
    "model_optical_axis",
    "perturbed_model",
    "pixel_ray",
    "pixel_rays",
    "project_point",
    "project_points",
    "project_rows",
    "sphere_point",
    "sphere_point_rates",
    "sphere_points",
    "unproject_pixels_to_plane",
    "unproject_pixels_to_sphere",
]

# The flat model: fx, fy, cx, cy; the 14 distortion coefficients; R (row-major); the centre in the eye
# frame; the tilted sensor's matrix and its inverse (row-major); whether any distortion is present.
_FX, _FY, _CX, _CY = 0, 1, 2, 3
_DIST = 4
_R = 18
_CENTRE = 27
_TILT = 30
_TILT_INVERSE = 39
_DISTORTED = 48
MODEL_SIZE = 49
_NEWTON_STEPS = 30
_NEWTON_TOLERANCE = 1e-14  # in normalized coordinates: 1e-10 px at a focal length of 10^4 px


def _tilt_matrix(tau_x: float, tau_y: float) -> np.ndarray:
    """OpenCV's tilted-sensor projection (``computeTiltProjectionMatrix``), shape (3, 3)."""
    cx, sx, cy, sy = np.cos(tau_x), np.sin(tau_x), np.cos(tau_y), np.sin(tau_y)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, sx], [0.0, -sx, cx]])
    rot_y = np.array([[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]])
    rot_xy = rot_y @ rot_x
    projection = np.array([[rot_xy[2, 2], 0.0, -rot_xy[0, 2]], [0.0, rot_xy[2, 2], -rot_xy[1, 2]], [0.0, 0.0, 1.0]])
    tilt: np.ndarray = projection @ rot_xy
    return tilt


@lru_cache(maxsize=16)
def camera_model(camera: Camera) -> np.ndarray:
    """The camera as the flat array (:data:`MODEL_SIZE`,) that the compiled kernels read (cached; do not modify)."""
    matrix = camera.matrix_px
    distortion = camera.distortion_coefficients
    tilt = _tilt_matrix(distortion[12], distortion[13])
    model = np.zeros(MODEL_SIZE)
    model[[_FX, _FY, _CX, _CY]] = matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2]
    model[_DIST : _DIST + 14] = distortion
    model[_R : _R + 9] = camera.rotation_to_camera.ravel()
    model[_CENTRE : _CENTRE + 3] = camera.center_in_eye
    model[_TILT : _TILT + 9] = tilt.ravel()
    model[_TILT_INVERSE : _TILT_INVERSE + 9] = np.linalg.inv(tilt).ravel()
    model[_DISTORTED] = float(np.any(distortion != 0.0))
    return model


@njit(cache=True)
def _distort(model: np.ndarray, x: float, y: float) -> tuple[float, float, float, float, float, float]:
    """OpenCV's radial, tangential and thin-prism distortion of normalized ``(x, y)``, before the tilt.

    Returns the distorted point and its Jacobian ``(dxd/dx, dxd/dy, dyd/dx, dyd/dy)``.
    """
    k1, k2, p1, p2, k3 = model[_DIST], model[_DIST + 1], model[_DIST + 2], model[_DIST + 3], model[_DIST + 4]
    k4, k5, k6 = model[_DIST + 5], model[_DIST + 6], model[_DIST + 7]
    s1, s2, s3, s4 = model[_DIST + 8], model[_DIST + 9], model[_DIST + 10], model[_DIST + 11]
    r2 = x * x + y * y
    numerator = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    denominator = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    radial = numerator / denominator
    d_numerator = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3)
    d_denominator = k4 + r2 * (2.0 * k5 + 3.0 * r2 * k6)
    d_radial = (d_numerator * denominator - numerator * d_denominator) / (denominator * denominator)  # d/d(r2)
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + s1 * r2 + s2 * r2 * r2
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y + s3 * r2 + s4 * r2 * r2
    dxx = radial + 2.0 * x * x * d_radial + 2.0 * p1 * y + 6.0 * p2 * x + 2.0 * x * (s1 + 2.0 * s2 * r2)
    dxy = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y + 2.0 * y * (s1 + 2.0 * s2 * r2)
    dyx = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y + 2.0 * x * (s3 + 2.0 * s4 * r2)
    dyy = radial + 2.0 * y * y * d_radial + 6.0 * p1 * y + 2.0 * p2 * x + 2.0 * y * (s3 + 2.0 * s4 * r2)
    return xd, yd, dxx, dxy, dyx, dyy


@njit(cache=True)
def _homography(matrix: np.ndarray, offset: int, x: float, y: float) -> tuple[float, float]:
    """``(x, y)`` through the 3x3 matrix stored row-major at ``matrix[offset:]``, dehomogenized."""
    hx = matrix[offset] * x + matrix[offset + 1] * y + matrix[offset + 2]
    hy = matrix[offset + 3] * x + matrix[offset + 4] * y + matrix[offset + 5]
    hz = matrix[offset + 6] * x + matrix[offset + 7] * y + matrix[offset + 8]
    return hx / hz, hy / hz


@njit(cache=True)
def project_point(model: np.ndarray, x: float, y: float, z: float) -> tuple[float, float]:
    """Pixel ``(u, v)`` of the eye-frame point ``(x, y, z)`` (``cv2.projectPoints``); NaN behind the camera."""
    dx, dy, dz = x - model[_CENTRE], y - model[_CENTRE + 1], z - model[_CENTRE + 2]
    xc = model[_R] * dx + model[_R + 1] * dy + model[_R + 2] * dz
    yc = model[_R + 3] * dx + model[_R + 4] * dy + model[_R + 5] * dz
    zc = model[_R + 6] * dx + model[_R + 7] * dy + model[_R + 8] * dz
    if not zc > 0.0:
        return np.nan, np.nan
    xn, yn = xc / zc, yc / zc
    if model[_DISTORTED] != 0.0:
        xn, yn, _, _, _, _ = _distort(model, xn, yn)
        xn, yn = _homography(model, _TILT, xn, yn)
    return model[_FX] * xn + model[_CX], model[_FY] * yn + model[_CY]


@njit(cache=True)
def _undistort(model: np.ndarray, u: float, v: float) -> tuple[float, float]:
    """Normalized undistorted ``(x, y)`` whose projection is pixel ``(u, v)`` (Newton's method); NaN if none."""
    xd, yd = (u - model[_CX]) / model[_FX], (v - model[_CY]) / model[_FY]
    if model[_DISTORTED] == 0.0:
        return xd, yd
    xd, yd = _homography(model, _TILT_INVERSE, xd, yd)
    x, y = xd, yd
    for _ in range(_NEWTON_STEPS):
        fx, fy, dxx, dxy, dyx, dyy = _distort(model, x, y)
        ex, ey = fx - xd, fy - yd
        determinant = dxx * dyy - dxy * dyx
        if determinant == 0.0 or not np.isfinite(determinant):
            return np.nan, np.nan
        step_x, step_y = (dyy * ex - dxy * ey) / determinant, (dxx * ey - dyx * ex) / determinant
        x, y = x - step_x, y - step_y
        if abs(step_x) + abs(step_y) < _NEWTON_TOLERANCE:
            return x, y
    fx, fy, _, _, _, _ = _distort(model, x, y)
    if abs(fx - xd) + abs(fy - yd) > 1e3 * _NEWTON_TOLERANCE:
        return np.nan, np.nan
    return x, y


@njit(cache=True)
def pixel_ray(model: np.ndarray, u: float, v: float) -> tuple[float, float, float]:
    """Unit direction, in the eye frame, of the ray from the camera's centre through pixel ``(u, v)``."""
    x, y = _undistort(model, u, v)
    return _ray_in_eye(model, x, y)


@njit(cache=True)
def _ray_in_eye(model: np.ndarray, x: float, y: float) -> tuple[float, float, float]:
    """Unit direction, in the eye frame, of the ray through normalized undistorted ``(x, y)``."""
    norm = np.sqrt(x * x + y * y + 1.0)
    x, y, z = x / norm, y / norm, 1.0 / norm
    return (
        model[_R] * x + model[_R + 3] * y + model[_R + 6] * z,
        model[_R + 1] * x + model[_R + 4] * y + model[_R + 7] * z,
        model[_R + 2] * x + model[_R + 5] * y + model[_R + 8] * z,
    )


@njit(cache=True)
def sphere_point(model: np.ndarray, u: float, v: float, radius: float) -> tuple[float, float, float]:
    """Where pixel ``(u, v)``'s ray meets the retina's bowl (Eq. 4.1-4.5 in general form); NaN off the bowl.

    The sphere of ``radius`` is centred at ``(0, 0, radius)``; the ray's far
    intersection is the bowl seen from above, and only ``z <= radius`` exists.
    """
    x, y = _undistort(model, u, v)
    return _bowl_point(model, x, y, radius)


@njit(cache=True)
def _bowl_point(model: np.ndarray, x: float, y: float, radius: float) -> tuple[float, float, float]:
    """:func:`sphere_point` of the ray through normalized undistorted ``(x, y)``."""
    dx, dy, dz = _ray_in_eye(model, x, y)
    ox, oy, oz = model[_CENTRE], model[_CENTRE + 1], model[_CENTRE + 2] - radius
    half_b = ox * dx + oy * dy + oz * dz
    disc = half_b * half_b - (ox * ox + oy * oy + oz * oz - radius * radius)
    if not disc >= 0.0:
        return np.nan, np.nan, np.nan
    t = -half_b + np.sqrt(disc)
    z = model[_CENTRE + 2] + t * dz
    if z > radius:
        return np.nan, np.nan, np.nan
    return model[_CENTRE] + t * dx, model[_CENTRE + 1] + t * dy, z


@njit(cache=True)
def model_centre(model: np.ndarray) -> np.ndarray:
    """The camera's centre in the eye frame (3,), mm, of a :func:`camera_model` (a view, not a copy)."""
    return model[_CENTRE : _CENTRE + 3]


@njit(cache=True)
def model_optical_axis(model: np.ndarray) -> np.ndarray:
    """The camera's optical axis in the eye frame (3,), the rotation's third row, of a :func:`camera_model`."""
    return model[_R + 6 : _R + 9]


@njit(cache=True)
def project_rows(model: np.ndarray, points: np.ndarray) -> np.ndarray:
    """:func:`project_points` of rows (N, 3) of points in the eye frame, mm, through a compiled ``model``
    (:func:`camera_model`), compiled for other kernels: pixels (N, 2), NaN behind the camera."""
    pixels = np.empty((len(points), 2))
    for n in range(len(points)):
        pixels[n, 0], pixels[n, 1] = project_point(model, points[n, 0], points[n, 1], points[n, 2])
    return pixels


@njit(cache=True)
def _ray_rows(model: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    rays = np.empty((len(pixels), 3))
    for n in range(len(pixels)):
        rays[n, 0], rays[n, 1], rays[n, 2] = pixel_ray(model, pixels[n, 0], pixels[n, 1])
    return rays


@njit(cache=True)
def sphere_points(model: np.ndarray, pixels: np.ndarray, radius: float) -> np.ndarray:
    """:func:`sphere_point` of each pixel (N, 2): points (N, 3) on the retina's bowl, NaN off it."""
    points = np.empty((len(pixels), 3))
    for n in range(len(pixels)):
        points[n, 0], points[n, 1], points[n, 2] = sphere_point(model, pixels[n, 0], pixels[n, 1], radius)
    return points


def check_last_axis(name: str, array: np.ndarray, size: int) -> np.ndarray:
    """``array`` as floats, checked to have shape (..., ``size``); a ``ValueError`` naming ``name`` if not."""
    array = np.asarray(array, dtype=float)
    if array.ndim == 0 or array.shape[-1] != size:
        raise ValueError(f"{name} must have shape (..., {size}), got {array.shape}")
    return array


def project_points(camera: Camera, points_in_eye: np.ndarray) -> np.ndarray:
    """Project eye-frame points to pixel coordinates, as ``cv2.projectPoints`` does.

    Parameters
    ----------
    camera : Camera
    points_in_eye : ndarray, shape (..., 3)
        Points in mm.

    Returns
    -------
    ndarray, shape (..., 2)
        ``(u, v)`` in pixels; NaN for points behind the camera.
    """
    points_in_eye = check_last_axis("points_in_eye", points_in_eye, 3)
    rows = np.ascontiguousarray(points_in_eye.reshape(-1, 3))
    return project_rows(camera_model(camera), rows).reshape(*points_in_eye.shape[:-1], 2)


def camera_depth_mm(camera: Camera, points_in_eye: np.ndarray) -> np.ndarray:
    """Depth of eye-frame points along the camera's optical axis (``z_cam``), shape (...), mm."""
    points_in_eye = check_last_axis("points_in_eye", points_in_eye, 3)
    depth: np.ndarray = points_in_eye @ camera.rotation_to_camera[2] + camera.translation_to_camera_mm[2]
    return depth


def pixel_rays(camera: Camera, pixels: np.ndarray) -> np.ndarray:
    """Unit directions, in the eye frame, of the rays through pixels (undistorted first).

    Parameters
    ----------
    camera : Camera
    pixels : ndarray, shape (..., 2)
        ``(u, v)`` in pixels.

    Returns
    -------
    ndarray, shape (..., 3)
        Unit vectors from the camera's centre :attr:`Camera.center_in_eye`.
    """
    pixels = check_last_axis("pixels", pixels, 2)
    rows = np.ascontiguousarray(pixels.reshape(-1, 2))
    return _ray_rows(camera_model(camera), rows).reshape(*pixels.shape[:-1], 3)


def unproject_pixels_to_sphere(camera: Camera, pixels: np.ndarray, radius_mm: float) -> np.ndarray:
    """Back-project pixels onto the retina sphere (exact Eq. 4.1-4.5, any camera pose and lens).

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
    pixels = check_last_axis("pixels", pixels, 2)
    rows = np.ascontiguousarray(pixels.reshape(-1, 2))
    return sphere_points(camera_model(camera), rows, float(radius_mm)).reshape(*pixels.shape[:-1], 3)


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
        Points on the plane in the eye frame; NaN where a ray does not go down to it.
    """
    origin = camera.center_in_eye
    if height_mm >= origin[2]:
        raise ValueError(f"the plane z = {height_mm:g} mm must lie below the camera ({origin[2]:g} mm)")
    rays = pixel_rays(camera, pixels)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(rays[..., 2] < 0, (origin[2] - height_mm) / -rays[..., 2], np.nan)
    points: np.ndarray = origin + t[..., None] * rays
    return points


CHANGE_SIZE = 14  # the camera parameters of perturbed_model


@njit(cache=True)
def perturbed_model(model: np.ndarray, change: np.ndarray) -> np.ndarray:
    """The camera ``model`` changed by ``change`` (:data:`CHANGE_SIZE`,): the cone fit's camera parameters.

    ``change`` holds, in order: the rotation of the camera about its own
    centre (a rotation vector about the camera's axes, radians:
    ``R' = exp([w]x) R``); the centre's shift in the eye frame (mm); the focal
    lengths' relative change (``fx' = fx (1 + s)``, likewise ``fy``); the
    principal point's shift (pixels); and the changes of OpenCV's first five
    distortion coefficients (``k1, k2, p1, p2, k3``).
    """
    out = model.copy()
    wx, wy, wz = change[0], change[1], change[2]
    angle = np.sqrt(wx * wx + wy * wy + wz * wz)
    if angle > 0.0:
        kx, ky, kz = wx / angle, wy / angle, wz / angle
        c, s = np.cos(angle), np.sin(angle)
        t = 1.0 - c
        rotation = np.array(
            [
                [c + kx * kx * t, kx * ky * t - kz * s, kx * kz * t + ky * s],
                [ky * kx * t + kz * s, c + ky * ky * t, ky * kz * t - kx * s],
                [kz * kx * t - ky * s, kz * ky * t + kx * s, c + kz * kz * t],
            ]
        )
        for i in range(3):
            for j in range(3):
                out[_R + 3 * i + j] = (
                    rotation[i, 0] * model[_R + j]
                    + rotation[i, 1] * model[_R + 3 + j]
                    + rotation[i, 2] * model[_R + 6 + j]
                )
    for i in range(3):
        out[_CENTRE + i] = model[_CENTRE + i] + change[3 + i]
    out[_FX] = model[_FX] * (1.0 + change[6])
    out[_FY] = model[_FY] * (1.0 + change[6])
    out[_CX] = model[_CX] + change[7]
    out[_CY] = model[_CY] + change[8]
    distorted = False
    for i in range(14):
        if i < 5:
            out[_DIST + i] = model[_DIST + i] + change[9 + i]
        distorted = distorted or out[_DIST + i] != 0.0
    out[_DISTORTED] = 1.0 if distorted else 0.0
    return out


@njit(cache=True)
def sphere_point_rates(model: np.ndarray, change: np.ndarray, pixels: np.ndarray, radius: float) -> np.ndarray:
    """How the points :func:`sphere_points` finds through ``perturbed_model(model, change)`` move: their
    derivatives with respect to the eye's radius and to each of ``change``'s values, differentiated through the
    model (the undistortion's by its implicit function).

    Parameters
    ----------
    model : ndarray, shape (MODEL_SIZE,)
    change : ndarray, shape (CHANGE_SIZE,)
        The camera's change (:func:`perturbed_model`'s units).
    pixels : ndarray, shape (N, 2)
    radius : float
        The eye's radius, mm.

    Returns
    -------
    ndarray, shape (N, 3, 1 + CHANGE_SIZE)
        ``d point / d radius`` (mm/mm), then ``d point / d change[k]``; zero for points off the bowl (and for a
        ray that grazes it, or where the lens model folds).
    """
    moved = perturbed_model(model, change)
    rotation = moved[_R : _R + 9].reshape(3, 3)
    # R' = exp([w]x) R with w about the camera's axes: each component of w turns the rays about this eye-frame axis.
    spin_axes = rotation.T @ np.ascontiguousarray(_rotation_rates(change[:3]))
    rates = np.zeros((len(pixels), 3, 1 + CHANGE_SIZE))
    moves = np.empty((2, 1 + CHANGE_SIZE))  # how the normalized point (x, y) moves, for the camera's own values
    for n in range(len(pixels)):
        u, v = pixels[n, 0], pixels[n, 1]
        x, y = _undistort(moved, u, v)
        px, py, pz = _bowl_point(moved, x, y, radius)
        if not np.isfinite(px + py + pz):
            continue
        ray = _ray_in_eye(moved, x, y)
        normal = (px, py, pz - radius)  # the sphere's outward normal times its radius
        along_normal = normal[0] * ray[0] + normal[1] * ray[1] + normal[2] * ray[2]
        _, _, dxx, dxy, dyx, dyy = _distort(moved, x, y)
        determinant = dxx * dyy - dxy * dyx
        if along_normal == 0.0 or determinant == 0.0:  # a ray that grazes the bowl, a lens that folds: held
            continue
        distance = (
            (px - moved[_CENTRE]) * ray[0] + (py - moved[_CENTRE + 1]) * ray[1] + (pz - moved[_CENTRE + 2]) * ray[2]
        )
        for i in range(3):
            rates[n, i, 0] = ray[i] * (radius + normal[2]) / along_normal  # the sphere grows about (0, 0, radius)
            for k in range(3):  # the camera's centre moves along the eye's axis k
                rates[n, i, 4 + k] = (1.0 if i == k else 0.0) - ray[i] * normal[k] / along_normal
        for k in range(3):
            axis = spin_axes[:, k]
            _write_turn(
                rates,
                n,
                1 + k,
                ray[1] * axis[2] - ray[2] * axis[1],
                ray[2] * axis[0] - ray[0] * axis[2],
                ray[0] * axis[1] - ray[1] * axis[0],
                ray,
                normal,
                along_normal,
                distance,
            )
        # The normalized point as the pixel's distorted one moves (through the tilt's homography, then the
        # distortion's inverse: its Jacobian's inverse), and as the distortion's coefficients change.
        xd, yd = (u - moved[_CX]) / moved[_FX], (v - moved[_CY]) / moved[_FY]
        t00, t01, t10, t11 = _homography_jacobian(moved, _TILT_INVERSE, xd, yd)
        i00, i01, i10, i11 = dyy / determinant, -dxy / determinant, -dyx / determinant, dxx / determinant
        a00, a01 = i00 * t00 + i01 * t10, i00 * t01 + i01 * t11
        a10, a11 = i10 * t00 + i11 * t10, i10 * t01 + i11 * t11
        focal = -1.0 / (1.0 + change[6])  # fx' = fx (1 + s), fy likewise
        moves[0, 7], moves[1, 7] = focal * (a00 * xd + a01 * yd), focal * (a10 * xd + a11 * yd)
        moves[0, 8], moves[1, 8] = -a00 / moved[_FX], -a10 / moved[_FX]
        moves[0, 9], moves[1, 9] = -a01 / moved[_FY], -a11 / moved[_FY]
        r2 = x * x + y * y
        radial = r2 / (1.0 + r2 * (moved[_DIST + 5] + r2 * (moved[_DIST + 6] + r2 * moved[_DIST + 7])))
        # d(distorted point) / d(k1, k2, p1, p2, k3)
        for k, (ex, ey) in enumerate(
            (
                (x * radial, y * radial),
                (x * radial * r2, y * radial * r2),
                (2.0 * x * y, r2 + 2.0 * y * y),
                (r2 + 2.0 * x * x, 2.0 * x * y),
                (x * radial * r2 * r2, y * radial * r2 * r2),
            )
        ):
            moves[0, 10 + k], moves[1, 10 + k] = -(i00 * ex + i01 * ey), -(i10 * ex + i11 * ey)
        norm = np.sqrt(x * x + y * y + 1.0)
        for k in range(7, 1 + CHANGE_SIZE):
            mx, my = moves[0, k], moves[1, k]
            along = (x * mx + y * my) / (norm * norm * norm)  # d[(x, y, 1) / norm] in the camera's frame
            cx, cy, cz = mx / norm - x * along, my / norm - y * along, -along
            _write_turn(
                rates,
                n,
                k,
                rotation[0, 0] * cx + rotation[1, 0] * cy + rotation[2, 0] * cz,
                rotation[0, 1] * cx + rotation[1, 1] * cy + rotation[2, 1] * cz,
                rotation[0, 2] * cx + rotation[1, 2] * cy + rotation[2, 2] * cz,
                ray,
                normal,
                along_normal,
                distance,
            )
    return rates


@njit(cache=True)
def _write_turn(
    rates: np.ndarray,
    n: int,
    k: int,
    tx: float,
    ty: float,
    tz: float,
    ray: tuple[float, float, float],
    normal: tuple[float, float, float],
    along_normal: float,
    distance: float,
) -> None:
    """Write into ``rates[n, :, k]`` how the bowl's point moves as its ray (from a fixed centre, ``distance`` to
    the point) turns at the rate ``(tx, ty, tz)``: along the sphere, whose ``normal`` it meets at ``along_normal``."""
    slide = distance * (normal[0] * tx + normal[1] * ty + normal[2] * tz) / along_normal
    rates[n, 0, k] = distance * tx - ray[0] * slide
    rates[n, 1, k] = distance * ty - ray[1] * slide
    rates[n, 2, k] = distance * tz - ray[2] * slide


@njit(cache=True)
def _rotation_rates(rotation_vector: np.ndarray) -> np.ndarray:
    """The left Jacobian of the rotation vector ``w`` (3,), (3, 3): ``d exp([w]x) / d w_k = [J e_k]x exp([w]x)``."""
    angle = np.sqrt(np.sum(rotation_vector * rotation_vector))
    if angle < 1e-4:
        first, second = 0.5 - angle * angle / 24.0, 1.0 / 6.0 - angle * angle / 120.0
    else:
        first, second = (1.0 - np.cos(angle)) / angle**2, (angle - np.sin(angle)) / angle**3
    wx, wy, wz = rotation_vector[0], rotation_vector[1], rotation_vector[2]
    skew = np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])
    jacobian: np.ndarray = np.eye(3) + first * skew + second * (skew @ skew)
    return jacobian


@njit(cache=True)
def _homography_jacobian(matrix: np.ndarray, offset: int, x: float, y: float) -> tuple[float, float, float, float]:
    """The Jacobian of :func:`_homography` at ``(x, y)``, row-major: ``(dX/dx, dX/dy, dY/dx, dY/dy)``."""
    hx = matrix[offset] * x + matrix[offset + 1] * y + matrix[offset + 2]
    hy = matrix[offset + 3] * x + matrix[offset + 4] * y + matrix[offset + 5]
    hz = matrix[offset + 6] * x + matrix[offset + 7] * y + matrix[offset + 8]
    px, py = hx / hz, hy / hz
    return (
        (matrix[offset] - px * matrix[offset + 6]) / hz,
        (matrix[offset + 1] - px * matrix[offset + 7]) / hz,
        (matrix[offset + 3] - py * matrix[offset + 6]) / hz,
        (matrix[offset + 4] - py * matrix[offset + 7]) / hz,
    )


def camera_of_model(camera: Camera, model: np.ndarray) -> Camera:
    """The calibrated :class:`Camera` that ``model`` describes, with ``camera``'s size and its distortion's length."""
    matrix = np.array([[model[_FX], 0.0, model[_CX]], [0.0, model[_FY], model[_CY]], [0.0, 0.0, 1.0]])
    count = 5 if camera.distortion is None else max(len(camera.distortion), 5)
    count = next(n for n in (5, 8, 12, 14) if n >= count)
    rotation = model[_R : _R + 9].reshape(3, 3)
    rotation = _nearest_rotation(rotation)
    translation = -rotation @ model[_CENTRE : _CENTRE + 3]
    return Camera.calibrated(
        camera.width_px, camera.height_px, matrix, model[_DIST : _DIST + count], rotation, translation, camera.response
    ).with_lens_of(camera)


def _nearest_rotation(matrix: np.ndarray) -> np.ndarray:
    """The rotation matrix nearest ``matrix`` (its polar factor), shape (3, 3)."""
    u, _, vt = np.linalg.svd(matrix)
    rotation: np.ndarray = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return rotation
