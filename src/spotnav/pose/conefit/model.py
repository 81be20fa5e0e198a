"""The compiled model of a cone fit: each edge point's residual from its edge cone, and the residuals' Jacobian.

An edge point is a pixel on a spot's edge. The camera (:mod:`spotnav.optics.camera`: OpenCV's lens and pose) turns it
into a ray, the ray meets the retina sphere, and the point there lies on its beam's *edge cone*: the cone of the edge
half-angle about the beam's axis, widened by the light's emitting radius (:func:`spotnav.optics.light.edge_angle`). A
point's residual is its angle from that cone, radians (the thesis's cone-sphere intersection, section 4.1, without
the planar approximation of 4.2). The kernels here read a problem's data as :class:`ConeArrays` (built by
:class:`spotnav.pose.conefit.problem.ConeProblem`) and differentiate the residual analytically in one pass over the
points.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from spotnav.optics.camera import CHANGE_SIZE, perturbed_model, sphere_point_rates, sphere_points
from spotnav.pose.conefit.parameters import _CAMERA, _CAMERA_END, _EDGE, _INSERTION, _LIGHT, _RADIUS, _TILT
from spotnav.setup.geometry import _beam_axes

__all__ = ["ConeArrays"]

_GROSS_RESIDUAL = 1.0  # radians: a point whose ray misses the bowl


class ConeArrays(NamedTuple):
    """A cone problem's data as the compiled kernels read it (see :class:`spotnav.pose.conefit.problem.ConeProblem`).

    Attributes
    ----------
    model : ndarray, shape (MODEL_SIZE,)
        The setup's camera (:func:`spotnav.optics.camera.camera_model`).
    base : ndarray, shape (6,)
        The setup's edge angle (rad), light radius, eye radius and insertion point (mm).
    beam_count : int
    tilt : float
        Beam tilt, radians.
    shared : ndarray, shape (SHARED_SIZE,)
        Start (or fixed value) of the geometry's changes, engine units.
    shared_index : ndarray of int, shape (SHARED_SIZE,)
        Where each shared parameter is in the free vector, -1 where fixed.
    frames : ndarray, shape (F, 6)
        Each frame's start (or fixed values).
    frame_index : ndarray of int, shape (F, 6)
        Where each frame's parameter is in the free vector, -1 where fixed.
    axis_mode : ndarray of int, shape (F,)
        :data:`spotnav.pose.conefit.parameters.AXIS_MODES` of each frame.
    known_axes : ndarray, shape (F, 3)
        The known axes (used where the mode is ``known``).
    pixels : ndarray, shape (N, 2)
        The edge points as detected.
    starts : ndarray of int, shape (F + 1,)
        Where each frame's points start, and where the last ends.
    beam : ndarray of int, shape (N,)
        The beam of each point.
    points_in_eye : ndarray, shape (N, 3)
        The points on the retina at the start's camera and eye radius, mm (NaN off the bowl).
    camera_free : bool
        Whether a free shared parameter moves the points on the retina (the eye's radius or the camera).
    """

    model: np.ndarray
    base: np.ndarray
    beam_count: int
    tilt: float
    shared: np.ndarray
    shared_index: np.ndarray
    frames: np.ndarray
    frame_index: np.ndarray
    axis_mode: np.ndarray
    known_axes: np.ndarray
    pixels: np.ndarray
    starts: np.ndarray
    beam: np.ndarray
    points_in_eye: np.ndarray
    camera_free: bool


@njit(cache=True)
def _dense_rows(values: np.ndarray, columns: np.ndarray, size: int) -> np.ndarray:
    """The matrix (N, size) whose row ``n`` holds ``values[n]`` in the columns ``columns[n]`` (summed if repeated)."""
    matrix = np.zeros((values.shape[0], size))
    for n in range(values.shape[0]):
        for a in range(values.shape[1]):
            matrix[n, columns[n, a]] += values[n, a]
    return matrix


@njit(cache=True)
def _unpack(
    x: np.ndarray, shared0: np.ndarray, shared_index: np.ndarray, frames0: np.ndarray, frame_index: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    shared = shared0.copy()
    for i in range(len(shared)):
        if shared_index[i] >= 0:
            shared[i] = x[shared_index[i]]
    frames = frames0.copy()
    for f in range(frames.shape[0]):
        for k in range(frames.shape[1]):
            if frame_index[f, k] >= 0:
                frames[f, k] = x[frame_index[f, k]]
    return shared, frames


@njit(cache=True)
def _instrument_axis(
    frame: np.ndarray, mode: int, insertion: np.ndarray, known_axis: np.ndarray
) -> tuple[float, float, float]:
    """The instrument axis of one frame's parameters (6,): through the insertion point, free or known."""
    if mode == 0:
        dx, dy, dz = frame[0] - insertion[0], frame[1] - insertion[1], frame[2] - insertion[2]
        norm = np.sqrt(dx * dx + dy * dy + dz * dz)
        return dx / norm, dy / norm, dz / norm
    if mode == 1:
        about_y, about_z = frame[3], frame[4]
        # rotation_about_z(about_z) @ rotation_about_y(about_y) @ (0, 0, -1)
        return -np.sin(about_y) * np.cos(about_z), -np.sin(about_y) * np.sin(about_z), -np.cos(about_y)
    return known_axis[0], known_axis[1], known_axis[2]


@njit(cache=True)
def _frame_beams(frame: np.ndarray, f: int, shared: np.ndarray, arrays: ConeArrays) -> np.ndarray:
    """The beam axes (B, 3) of one frame's parameters ``frame`` (6,), frame ``f``'s axis mode."""
    insertion = np.empty(3)
    for i in range(3):
        insertion[i] = arrays.base[3 + i] + shared[_INSERTION + i]
    axis = np.empty(3)
    axis[0], axis[1], axis[2] = _instrument_axis(frame, arrays.axis_mode[f], insertion, arrays.known_axes[f])
    return _beam_axes(axis, arrays.beam_count, arrays.tilt + shared[_TILT], frame[5])


@njit(cache=True)
def _frame_residuals(
    out: np.ndarray, points: np.ndarray, f: int, frames: np.ndarray, shared: np.ndarray, arrays: ConeArrays
) -> None:
    """Residuals of frame ``f``'s points (written into ``out``) for the values ``shared`` and ``frames``."""
    base, starts, beam_of = arrays.base, arrays.starts, arrays.beam
    beams = _frame_beams(frames[f], f, shared, arrays)
    edge, light = base[0] + shared[_EDGE], base[1] + shared[_LIGHT]
    tx, ty, tz = frames[f, 0], frames[f, 1], frames[f, 2]
    for n in range(starts[f], starts[f + 1]):
        b = beam_of[n]
        x, y, z = points[n, 0] - tx, points[n, 1] - ty, points[n, 2] - tz
        if not np.isfinite(x + y + z):
            out[n] = _GROSS_RESIDUAL
            continue
        along = x * beams[b, 0] + y * beams[b, 1] + z * beams[b, 2]
        across = np.sqrt(max(x * x + y * y + z * z - along * along, 0.0))
        # Ahead of the tip, atan of the ratio: half the time of atan2, the same angle to the last bit or two.
        angle = np.arctan((across - light) / along) if along > 0.0 else np.arctan2(across - light, along)
        out[n] = angle - edge


@njit(cache=True)
def _points_at(shared: np.ndarray, arrays: ConeArrays) -> np.ndarray:
    """The points on the sphere for the shared values (the cached ones when the camera and eye are fixed)."""
    if not arrays.camera_free:
        return arrays.points_in_eye
    model = perturbed_model(arrays.model, shared[_CAMERA:_CAMERA_END])
    return sphere_points(model, arrays.pixels, arrays.base[_RADIUS] + shared[_RADIUS])


@njit(cache=True)
def _all_residuals(points: np.ndarray, frames: np.ndarray, shared: np.ndarray, arrays: ConeArrays) -> np.ndarray:
    out = np.empty(len(points))
    for f in range(frames.shape[0]):
        _frame_residuals(out, points, f, frames, shared, arrays)
    return out


@njit(cache=True)
def _residuals(x: np.ndarray, arrays: ConeArrays) -> np.ndarray:
    shared, frames = _unpack(x, arrays.shared, arrays.shared_index, arrays.frames, arrays.frame_index)
    return _all_residuals(_points_at(shared, arrays), frames, shared, arrays)


@njit(cache=True)
def _shared_columns(x: np.ndarray, arrays: ConeArrays, ids: np.ndarray) -> np.ndarray:
    """Each point's derivatives (N, len(ids)) with respect to the shared parameters ``ids``.

    Differentiated through the residual of :func:`_frame_residuals` and the points on the sphere
    (:func:`spotnav.optics.camera.sphere_point_rates`) in one pass over the points; only the beam axes' derivatives with
    respect to the insertion point and the beams' tilt (per frame, not per point) are central differences.
    """
    shared, frames = _unpack(x, arrays.shared, arrays.shared_index, arrays.frames, arrays.frame_index)
    base, starts, beam_of = arrays.base, arrays.starts, arrays.beam
    points = _points_at(shared, arrays)
    light = base[1] + shared[_LIGHT]
    columns = np.zeros((len(points), len(ids)))
    point_rates = np.zeros((0, 3, 1 + CHANGE_SIZE))
    if np.any((ids >= _RADIUS) & (ids < _CAMERA_END)):
        radius = base[_RADIUS] + shared[_RADIUS]
        point_rates = sphere_point_rates(arrays.model, shared[_CAMERA:_CAMERA_END], arrays.pixels, radius)
    beam_rates = np.zeros((len(ids), arrays.beam_count, 3))  # d(beam axis) / d(parameter)
    for f in range(frames.shape[0]):
        beams = _frame_beams(frames[f], f, shared, arrays)
        for j in range(len(ids)):
            if ids[j] >= _INSERTION:
                beam_rates[j] = _beam_rate(frames[f], f, shared, arrays, ids[j], True)
        for n in range(starts[f], starts[f + 1]):
            b = beam_of[n]
            offset = (points[n, 0] - frames[f, 0], points[n, 1] - frames[f, 1], points[n, 2] - frames[f, 2])
            if not np.isfinite(offset[0] + offset[1] + offset[2]):
                continue  # a gross residual, held
            gradient, axial, light_rate = _point_rates(offset, _row(beams, b), light)
            for j in range(len(ids)):
                i = ids[j]
                if i == _EDGE:
                    columns[n, j] = -1.0
                elif i == _LIGHT:
                    columns[n, j] = light_rate
                elif i < _CAMERA_END:
                    rate = point_rates[n, :, i - _RADIUS]
                    columns[n, j] = gradient[0] * rate[0] + gradient[1] * rate[1] + gradient[2] * rate[2]
                else:
                    rate = beam_rates[j, b]
                    columns[n, j] = axial * (offset[0] * rate[0] + offset[1] * rate[1] + offset[2] * rate[2])
    return columns


@njit(cache=True)
def _frame_columns(x: np.ndarray, arrays: ConeArrays, per_frame: int) -> tuple[np.ndarray, np.ndarray]:
    """Each point's derivatives with respect to its own frame's ``per_frame`` free parameters, and their columns.

    Differentiated through the residual of :func:`_frame_residuals` in one pass over the points; only the beam
    axes' derivatives (per frame, not per point) are central differences.
    """
    shared, frames = _unpack(x, arrays.shared, arrays.shared_index, arrays.frames, arrays.frame_index)
    base, frame_index, starts, beam_of = arrays.base, arrays.frame_index, arrays.starts, arrays.beam
    points = _points_at(shared, arrays)
    light = base[1] + shared[_LIGHT]
    values = np.zeros((len(points), per_frame))
    columns = np.zeros((len(points), per_frame), dtype=np.int64)
    free = np.empty(per_frame, dtype=np.int64)
    beam_rates = np.empty((per_frame, arrays.beam_count, 3))  # d(beam axis) / d(parameter)
    for f in range(frames.shape[0]):
        beams = _frame_beams(frames[f], f, shared, arrays)
        j = 0
        for k in range(frames.shape[1]):
            if frame_index[f, k] < 0:
                continue
            free[j] = k
            beam_rates[j] = _beam_rate(frames[f], f, shared, arrays, k, False)
            j += 1
        for n in range(starts[f], starts[f + 1]):
            b = beam_of[n]
            for j in range(per_frame):
                columns[n, j] = frame_index[f, free[j]]
            offset = (points[n, 0] - frames[f, 0], points[n, 1] - frames[f, 1], points[n, 2] - frames[f, 2])
            if not np.isfinite(offset[0] + offset[1] + offset[2]):
                continue  # a gross residual, held
            gradient, axial, _ = _point_rates(offset, _row(beams, b), light)
            for j in range(per_frame):
                k, rate = free[j], beam_rates[j, b]
                values[n, j] = axial * (offset[0] * rate[0] + offset[1] * rate[1] + offset[2] * rate[2])
                if k < 3:  # the tip moves the other way from the point
                    values[n, j] -= gradient[k]
    return values, columns


@njit(cache=True, inline="always")
def _row(matrix: np.ndarray, i: int) -> tuple[float, float, float]:
    """Row ``i`` of ``matrix`` (M, 3) as three numbers: a per-point kernel handed them, not a view of the row, runs
    a third faster (a Jacobian of 242 points: 6.5 -> 4.5 us)."""
    return matrix[i, 0], matrix[i, 1], matrix[i, 2]


@njit(cache=True)
def _point_rates(
    offset: tuple[float, float, float], beam: tuple[float, float, float], light: float
) -> tuple[tuple[float, float, float], float, float]:
    """The rates of a point's residual ``atan2(across - light, along) - edge``, ``offset`` = point - tip and
    ``beam`` its beam's axis (three numbers each): its gradient with respect to the point (the tip's is its
    negative), its rate per unit of ``along`` at a fixed distance from the tip (a turn of the beam moves ``along``
    by the offset times the axis's rate), and its rate with respect to the light's radius."""
    along = offset[0] * beam[0] + offset[1] * beam[1] + offset[2] * beam[2]
    across = np.sqrt(max(offset[0] ** 2 + offset[1] ** 2 + offset[2] ** 2 - along * along, 0.0))
    height = across - light
    scale = 1.0 / (height * height + along * along)
    lean = along / across if across > 0.0 else 0.0
    axial = -(along * lean + height) * scale
    radial = lean * scale  # per unit of half the squared distance from the tip
    gradient = (
        radial * offset[0] + axial * beam[0],
        radial * offset[1] + axial * beam[1],
        radial * offset[2] + axial * beam[2],
    )
    return gradient, axial, -along * scale


@njit(cache=True)
def _beam_rate(
    frame: np.ndarray, f: int, shared: np.ndarray, arrays: ConeArrays, k: int, of_shared: bool
) -> np.ndarray:
    """Central-difference derivative (B, 3) of frame ``f``'s beam axes with respect to its parameter ``k`` of
    ``frame`` (6,), or with ``of_shared`` to the shared parameter ``k``."""
    values = shared if of_shared else frame
    # The insertion point turns the axis over ten or more mm: a wider step, whose rounding (eps / step) stays a
    # millionth of the along-axis change even where a point's offset nearly cancels the rate it is multiplied by.
    step = (1e-4 if of_shared else 1e-6) * max(abs(values[k]), 1.0)
    up, down = values.copy(), values.copy()
    up[k] += step
    down[k] -= step
    if of_shared:
        rising, falling = _frame_beams(frame, f, up, arrays), _frame_beams(frame, f, down, arrays)
    else:
        rising, falling = _frame_beams(up, f, shared, arrays), _frame_beams(down, f, shared, arrays)
    rate: np.ndarray = (rising - falling) / (2 * step)
    return rate
