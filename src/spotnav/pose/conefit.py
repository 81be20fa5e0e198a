"""The cone-fit engine: one model of the edge points, one residual with its Jacobian, one robust fit.

Every precise estimate in spotnav is a problem for this module: localizing a
frame, tracking it, calibrating the geometry from known poses and fitting the
eye's radius over a sequence differ only in which parameters are free.

The model. An edge point is a pixel on a spot's edge. The camera
(:mod:`spotnav.optics.camera`: OpenCV's lens and pose) turns it into a ray, the ray
meets the retina sphere, and the point there lies on its beam's *edge cone*:
the cone of the edge half-angle about the beam's axis, widened by the light's
emitting radius (:func:`edge_angle`). A point's residual is its angle from that
cone, radians (the thesis's cone-sphere intersection, section 4.1, without
the planar approximation of 4.2).

The parameters. Shared by all frames, the geometry (:data:`SHARED_SIZE`
values, :data:`spotnav.setup.uncertainty.GEOMETRY_PARAMETERS`, each a change of the
setup's value): the edge angle, the light's radius, the eye's radius, the
camera's rotation, centre, focal length, principal point and distortion, and
the insertion point. Per frame (:data:`FRAME_PARAMETERS`): the tip, the
instrument axis (through the insertion point, free as two angles, or known)
and the roll of three beams.

The fit (:func:`fit_cones`): a robust soft-L1 fit finds the outliers (points
over 3 robust sigmas off), a least-squares fit of the rest gives the
parameters, and its covariance adds, to the points' own scatter, the shift of
each spot's whole edge and the uncertainty of the geometry that was held
fixed (:func:`geometry_covariance`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property, lru_cache, partial

import numpy as np
from numba import njit
from numba.extending import overload
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix, vstack

from spotnav.optics.camera import (
    CHANGE_SIZE,
    camera_model,
    camera_of_model,
    perturbed_model,
    sphere_point_rates,
    sphere_points,
)
from spotnav.setup.config import Setup
from spotnav.setup.geometry import _axis_rotations, _beam_axes, edge_angle_of_blend, normalize
from spotnav.setup.uncertainty import GEOMETRY_PARAMETERS

__all__ = [
    "AXIS_MODES",
    "DEFAULT_BLEND",
    "EDGE_CONTOUR_SIGMA",
    "EDGE_MODEL_SIGMA",
    "FRAME_PARAMETERS",
    "PARAMETER_GROUPS",
    "SHARED_SIZE",
    "SOLVERS",
    "ConeProblem",
    "ConeSolution",
    "EdgePoints",
    "FitUncertainty",
    "cone_problem",
    "correlation_inflation",
    "edge_angle",
    "fit_cones",
    "geometry_covariance",
    "geometry_to_file_units",
    "geometry_values",
    "group_of",
    "prior_sigmas",
    "robust_sigma",
    "scatter_covariance",
    "setup_with_geometry",
]

DEFAULT_BLEND = 0.15  # Blender's default spot_blend: the edge model when the setup gives none
# The edge model's own uncertainty (shared by all spots: how the half-light level follows the light) and the shift
# of one spot's whole edge by the texture and vessels under it (each spot its own; some 0.006-0.0095 deg rms over
# the 5000 px paths at 1-2 W).
EDGE_MODEL_SIGMA = float(np.radians(0.003))
EDGE_CONTOUR_SIGMA = float(np.radians(0.007))

SHARED_SIZE = len(GEOMETRY_PARAMETERS)
_EDGE, _LIGHT, _RADIUS, _CAMERA = 0, 1, 2, 3  # where each part of the shared vector starts
_CAMERA_END = _INSERTION = _CAMERA + CHANGE_SIZE
# File units (degrees, per cent) to the engine's (radians, fractions), per shared parameter.
_TO_ENGINE = np.ones(SHARED_SIZE)
_TO_ENGINE[[_EDGE, _CAMERA, _CAMERA + 1, _CAMERA + 2]] = np.pi / 180.0
_TO_ENGINE[_CAMERA + 6] = 0.01
# A lens's distortion beyond k1 is smaller: these shares of the stated displacement for k2, k3 and p1, p2.
_K2_SHARE, _K3_SHARE, _TANGENTIAL_SHARE = 0.5, 0.25, 0.25
# The shared parameters by what they describe (the names calibrate's flags use).
PARAMETER_GROUPS: dict[str, tuple[int, ...]] = {
    "edge-angle": (_EDGE,),
    "light-radius": (_LIGHT,),
    "eye-radius": (_RADIUS,),
    "camera-rotation": (_CAMERA, _CAMERA + 1, _CAMERA + 2),
    "camera-position": (_CAMERA + 3, _CAMERA + 4, _CAMERA + 5),
    "focal-length": (_CAMERA + 6,),
    "principal-point": (_CAMERA + 7, _CAMERA + 8),
    "distortion": tuple(range(_CAMERA + 9, _CAMERA_END)),
    "insertion-point": (_INSERTION, _INSERTION + 1, _INSERTION + 2),
}


def group_of(index: int) -> str:
    """The :data:`PARAMETER_GROUPS` name of a shared parameter."""
    return next(name for name, ids in PARAMETER_GROUPS.items() if index in ids)


FRAME_PARAMETERS = ("tip_x_mm", "tip_y_mm", "tip_z_mm", "about_y", "about_z", "roll")
_FRAME_SIZE = len(FRAME_PARAMETERS)
AXIS_MODES = {"insertion": 0, "free": 1, "known": 2}
SOLVERS = ("trust-region", "levenberg-marquardt", "gauss-newton")
_GAUSS_NEWTON = SOLVERS.index("gauss-newton")
_LEVENBERG_MARQUARDT = SOLVERS.index("levenberg-marquardt")
_GROSS_RESIDUAL = 1.0  # radians: a point whose ray misses the bowl


def edge_angle(setup: Setup) -> float:
    """The edge model's half-angle, radians: ``instrument.edge_half_angle_deg`` or its default.

    The default is the half-light angle of a Cycles spot of the nominal half-angle
    with Blender's default blend 0.15 (:func:`spotnav.setup.geometry.edge_angle_of_blend`).
    """
    instrument = setup.instrument
    if instrument.edge_half_angle_deg is not None:
        return float(np.radians(instrument.edge_half_angle_deg))
    return edge_angle_of_blend(instrument.beam_half_angle, DEFAULT_BLEND)


def prior_sigmas(setup: Setup) -> np.ndarray:
    """The ``[uncertainty]`` section as 1-sigma values of the shared parameters, engine units, shape (SHARED_SIZE,).

    A distortion's displacement at the middle of the image's edge (``r``, in
    normalized coordinates) becomes a coefficient: ``px / (f r^3)`` for ``k1``;
    the higher radial terms and the tangential ones, smaller in real lenses,
    get a share of it (:data:`_K2_SHARE`, :data:`_K3_SHARE`,
    :data:`_TANGENTIAL_SHARE`): ``r^5`` for ``k2``, ``r^7`` for ``k3``,
    ``r^2`` for ``p1`` and ``p2``.
    """
    uncertainty, camera = setup.uncertainty, setup.camera
    focal = camera.focal_px
    edge = 0.5 * max(camera.width_px, camera.height_px) / focal
    distortion = uncertainty.distortion_px / focal
    principal_px = uncertainty.principal_point_percent / 100.0 * camera.width_px
    values = np.array(
        [
            uncertainty.edge_half_angle_deg,
            uncertainty.light_radius_mm,
            uncertainty.eye_radius_mm,
            *[uncertainty.camera_rotation_deg] * 3,
            *[uncertainty.camera_position_mm] * 3,
            uncertainty.focal_length_percent,
            principal_px,
            principal_px,
            distortion / edge**3,
            _K2_SHARE * distortion / edge**5,
            _TANGENTIAL_SHARE * distortion / edge**2,
            _TANGENTIAL_SHARE * distortion / edge**2,
            _K3_SHARE * distortion / edge**7,
            *[uncertainty.insertion_point_mm] * 3,
        ]
    )
    return values * _TO_ENGINE


def geometry_values(setup: Setup) -> np.ndarray:
    """The setup's geometry in the units of :data:`GEOMETRY_PARAMETERS`, shape (SHARED_SIZE,).

    The values that the changes add to: the edge angle (deg), light and eye
    radii, the camera's centre in the eye frame, its principal point and
    distortion coefficients, the insertion point; 0 for the rotation and the
    focal length's percentage (changes only).
    """
    camera = setup.camera
    values = np.zeros(SHARED_SIZE)
    values[_EDGE] = np.degrees(edge_angle(setup))
    values[_LIGHT] = setup.instrument.light_radius_mm
    values[_RADIUS] = setup.eye.radius_mm
    values[_CAMERA + 3 : _CAMERA + 6] = camera.center_in_eye
    values[_CAMERA + 7 : _CAMERA + 9] = camera.principal_point_px
    values[_CAMERA + 9 : _CAMERA_END] = camera.distortion_coefficients[:5]
    values[_INSERTION:] = setup.instrument.insertion_in_eye
    return values


def setup_with_geometry(setup: Setup, shared: np.ndarray) -> Setup:
    """The setup with the geometry's changes ``shared`` (SHARED_SIZE,), engine units, in place.

    A changed camera is written as a calibrated one (OpenCV's terms); a light
    radius fitted below zero is a point (0).
    """
    shared = np.asarray(shared, dtype=float)
    camera = setup.camera
    if np.any(shared[_CAMERA:_CAMERA_END] != 0.0):
        camera = camera_of_model(camera, perturbed_model(camera_model(camera), shared[_CAMERA:_CAMERA_END]))
    instrument = replace(
        setup.instrument,
        edge_half_angle_deg=float(np.degrees(edge_angle(setup) + shared[_EDGE])),
        light_radius_mm=max(float(setup.instrument.light_radius_mm + shared[_LIGHT]), 0.0),
        insertion_point_mm=tuple(float(v) for v in setup.instrument.insertion_in_eye + shared[_INSERTION:]),
    )
    eye = replace(setup.eye, radius_mm=float(setup.eye.radius_mm + shared[_RADIUS]))
    return replace(setup, camera=camera, eye=eye, instrument=instrument)


def geometry_to_file_units(values: np.ndarray) -> np.ndarray:
    """Shared parameters (..., SHARED_SIZE) from engine units to those of :data:`GEOMETRY_PARAMETERS`."""
    return np.asarray(values, dtype=float) / _TO_ENGINE


@lru_cache(maxsize=32)
def geometry_covariance(setup: Setup, *, one_frame: bool = True) -> np.ndarray:
    """How well the setup's geometry is known: the shared parameters' covariance, engine units, (SHARED_SIZE,)*2.

    ``[calibration]``'s covariance for the parameters it lists, ``[uncertainty]``
    for the others, and with ``one_frame`` the edge model's error in one
    frame: the one the calibration measured, at least :data:`EDGE_MODEL_SIGMA`
    (a pose's; a calibration over many frames measures that error itself).
    Computed once per setup (every tracked frame asks): the array is read-only.
    """
    covariance = np.diag(prior_sigmas(setup) ** 2)
    record = setup.calibration
    if record.parameters:
        index = [GEOMETRY_PARAMETERS.index(name) for name in record.parameters]
        scale = _TO_ENGINE[index]
        block = np.array(record.covariance, dtype=float) * np.outer(scale, scale)
        covariance[index, :] = 0.0
        covariance[:, index] = 0.0
        covariance[np.ix_(index, index)] = block
    if one_frame:
        covariance[_EDGE, _EDGE] += max(EDGE_MODEL_SIGMA, np.radians(record.frame_edge_sigma_deg)) ** 2
    covariance.setflags(write=False)
    return covariance


@dataclass(frozen=True)
class EdgePoints:
    """Which edge points came from which spot, beam and frame.

    Attributes
    ----------
    pixels : ndarray, shape (N, 2)
        ``(u, v)`` as detected (distorted), in order around each spot.
    frame : ndarray of int, shape (N,)
        The frame of each point, 0 to F - 1, nondecreasing.
    beam : ndarray of int, shape (N,)
        The beam that made each point's spot.
    spot : ndarray of int, shape (N,)
        Which spot (contour) each point lies on, numbered over all frames.
    spot_sigma : ndarray, shape (at least max(spot) + 1,), or None
        Each spot's own whole-edge uncertainty beyond the common one (a blur
        of unknown kind), radians; None: none.
    """

    pixels: np.ndarray
    frame: np.ndarray
    beam: np.ndarray
    spot: np.ndarray
    spot_sigma: np.ndarray | None = None

    def __post_init__(self) -> None:
        pixels = np.ascontiguousarray(self.pixels, dtype=float).reshape(-1, 2)
        count = len(pixels)
        for name in ("frame", "beam", "spot"):
            values = np.ascontiguousarray(getattr(self, name), dtype=np.int64)
            if values.shape != (count,):
                raise ValueError(f"{name} must have shape ({count},), got {values.shape}")
            object.__setattr__(self, name, values)
        ordered, spots = _frame_order(self.frame, self.spot)
        if not ordered:
            raise ValueError("edge points must be in frame order, their spots numbered from 0")
        object.__setattr__(self, "pixels", pixels)
        sigma = np.zeros(spots) if self.spot_sigma is None else np.asarray(self.spot_sigma, dtype=float)
        if sigma.ndim != 1 or len(sigma) < spots:
            raise ValueError(f"spot_sigma must have shape (at least {spots},), got {sigma.shape}")
        object.__setattr__(self, "spot_sigma", sigma)

    @classmethod
    def of_frames(
        cls,
        spots_px: Sequence[Sequence[np.ndarray]],
        beams: Sequence[Sequence[int]],
        spot_sigma: Sequence[Sequence[float]] | None = None,
    ) -> EdgePoints:
        """Points from each frame's spots' edges (``spots_px[f][k]``, shape (N_k, 2)), their beams and own sigmas."""
        pixels, spots = [np.zeros((0, 2))], []
        for f, (edges, frame_beams) in enumerate(zip(spots_px, beams, strict=True)):
            for edge, b in zip(edges, frame_beams, strict=True):
                pixels.append(np.asarray(edge, dtype=float).reshape(-1, 2))
                spots.append((len(pixels[-1]), f, b))
        sigma = None if spot_sigma is None else np.concatenate([np.asarray(s, dtype=float) for s in spot_sigma])
        labels = _spot_rows(np.array(spots, dtype=np.int64).reshape(-1, 3))
        return cls(np.concatenate(pixels), *labels, spot_sigma=sigma)

    def subset(self, keep: np.ndarray) -> EdgePoints:
        """The points where ``keep`` (N,) is true, in order (the spots keep their numbers)."""
        return EdgePoints(self.pixels[keep], self.frame[keep], self.beam[keep], self.spot[keep], self.spot_sigma)


@njit(cache=True)
def _spot_rows(spots: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each point's frame, beam and spot (N,) from each spot's (point count, frame, beam) (K, 3), the spots numbered
    in order."""
    total = 0
    for k in range(len(spots)):
        total += spots[k, 0]
    frame, beam, spot = np.empty(total, np.int64), np.empty(total, np.int64), np.empty(total, np.int64)
    n = 0
    for k in range(len(spots)):
        for _ in range(spots[k, 0]):
            frame[n], beam[n], spot[n] = spots[k, 1], spots[k, 2], k
            n += 1
    return frame, beam, spot


@njit(cache=True)
def _frame_order(frame: np.ndarray, spot: np.ndarray) -> tuple[bool, int]:
    """Whether the points' frames (N,) never decrease and their spot numbers (N,) are not negative, and how many
    spots those numbers reach (max + 1)."""
    ordered, spots = True, 0
    for n in range(len(frame)):
        ordered = ordered and (n == 0 or frame[n] >= frame[n - 1]) and spot[n] >= 0
        spots = max(spots, spot[n] + 1)
    return ordered, spots


@njit(cache=True)
def _frame_starts(frame: np.ndarray, count: int) -> np.ndarray:
    """Where each of ``count`` frames' points start in the points' frames (N,), in frame order, and where the last
    ends (count + 1,): ``np.searchsorted(frame, range(count + 1))``."""
    starts = np.empty(count + 1, np.int64)
    n = 0
    for f in range(count + 1):
        while n < len(frame) and frame[n] < f:
            n += 1
        starts[f] = n
    return starts


@lru_cache(maxsize=64)
def _parameter_index(
    free_shared: tuple[int, ...], free_frame: tuple[int, ...], count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Where each shared parameter (SHARED_SIZE,) and each frame's parameter (count, 6) is in the free vector, -1
    where fixed: the free shared parameters first, then each frame's own in turn (read-only)."""
    shared_index = np.full(SHARED_SIZE, -1, dtype=np.int64)
    shared_index[list(free_shared)] = np.arange(len(free_shared))
    frame_index = np.full((count, _FRAME_SIZE), -1, dtype=np.int64)
    offset = len(free_shared)
    for f in range(count):
        for k in free_frame:
            frame_index[f, k] = offset
            offset += 1
    shared_index.setflags(write=False)
    frame_index.setflags(write=False)
    return shared_index, frame_index


@dataclass(frozen=True)
class ConeProblem:
    """A cone fit: the edge points, the geometry they are seen in, the start, and what is free.

    Build it with :func:`cone_problem`.

    Attributes
    ----------
    model : ndarray, shape (MODEL_SIZE,)
        The setup's camera (:func:`spotnav.optics.camera.camera_model`).
    base : ndarray, shape (6,)
        The setup's edge angle (rad), light radius, eye radius and insertion point (mm).
    beam_count : int
    tilt : float
        Beam tilt, radians.
    points : EdgePoints
    frames : ndarray, shape (F, 6)
        Each frame's start: tip (mm), axis angles about y and z (rad, see
        :func:`spotnav.setup.geometry.axis_rotations`) and roll (rad).
    axis_mode : ndarray of int, shape (F,)
        :data:`AXIS_MODES`: through the insertion point, free, or known.
    known_axes : ndarray, shape (F, 3)
        The known axes (used where the mode is ``known``).
    shared : ndarray, shape (SHARED_SIZE,)
        Start (or fixed value) of the geometry's changes, engine units.
    free_shared : tuple of int
        Shared parameters to fit.
    free_frame : tuple of int
        Per-frame parameters to fit (indices of :data:`FRAME_PARAMETERS`), the same for every frame.
    prior : ndarray, shape (SHARED_SIZE, SHARED_SIZE)
        The geometry's covariance (:func:`geometry_covariance`): what the fixed
        shared parameters add to the fit's covariance.
    """

    model: np.ndarray
    base: np.ndarray
    beam_count: int
    tilt: float
    points: EdgePoints
    frames: np.ndarray
    axis_mode: np.ndarray
    known_axes: np.ndarray
    shared: np.ndarray
    free_shared: tuple[int, ...]
    free_frame: tuple[int, ...]
    prior: np.ndarray
    _arrays: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        frames = np.ascontiguousarray(self.frames, dtype=float).reshape(-1, _FRAME_SIZE)
        count = len(frames)
        shared_index, frame_index = _parameter_index(self.free_shared, self.free_frame, count)
        starts = _frame_starts(self.points.frame, count)
        camera_free = any(_RADIUS <= i < _CAMERA_END for i in self.free_shared)
        model = perturbed_model(self.model, self.shared[_CAMERA:_CAMERA_END])
        cached = sphere_points(model, self.points.pixels, self.base[_RADIUS] + self.shared[_RADIUS])
        arrays = (
            np.ascontiguousarray(self.model, dtype=float),
            np.ascontiguousarray(self.base, dtype=float),
            int(self.beam_count),
            float(self.tilt),
            np.ascontiguousarray(self.shared, dtype=float),
            shared_index,
            frames,
            frame_index,
            np.ascontiguousarray(self.axis_mode, dtype=np.int64),
            np.ascontiguousarray(self.known_axes, dtype=float).reshape(-1, 3),
            self.points.pixels,
            starts,
            self.points.beam,
            cached,
            camera_free,
        )
        object.__setattr__(self, "frames", frames)
        object.__setattr__(self, "_arrays", arrays)

    @property
    def size(self) -> int:
        """Number of free parameters."""
        return len(self.free_shared) + len(self.free_frame) * len(self.frames)

    @property
    def points_in_eye(self) -> np.ndarray:
        """The points on the retina at the start's camera and eye radius, shape (N, 3), mm (NaN off the bowl)."""
        return self._arrays[13]

    @property
    def start(self) -> np.ndarray:
        """The free parameters' start, shape (size,)."""
        frame_index = self._arrays[7]
        x = np.empty(self.size)
        if self.free_shared:
            x[: len(self.free_shared)] = self.shared[list(self.free_shared)]
        free = frame_index >= 0
        x[frame_index[free]] = self.frames[free]
        return x

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The shared (SHARED_SIZE,) and per-frame (F, 6) values at the free parameters ``x``."""
        return _unpack(np.asarray(x, dtype=float), *self._arrays[4:8])

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Each point's angle from its edge cone at ``x``, radians, shape (N,)."""
        return _residuals(np.asarray(x, dtype=float), self._arrays)

    def jacobian(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The residuals' Jacobian at ``x`` as rows of ``(values, columns)``, each shape (N, W).

        Row ``n`` has its nonzero entries ``values[n]`` in the columns
        ``columns[n]``: the free shared parameters, then its frame's own.
        """
        x = np.asarray(x, dtype=float)
        values, columns = _frame_columns(x, self._arrays, len(self.free_frame))
        if not self.free_shared:
            return values, columns
        shared_ids = np.array(self.free_shared, dtype=np.int64)
        shared_columns = _shared_columns(x, self._arrays, shared_ids)
        shared_positions = np.broadcast_to(np.arange(len(shared_ids)), shared_columns.shape)
        return np.hstack([shared_columns, values]), np.hstack([shared_positions, columns])

    def jacobian_matrix(self, x: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray | csr_matrix:
        """The Jacobian at ``x`` (of the ``rows`` kept), dense when small, else sparse (CSR)."""
        values, columns = self.jacobian(x)
        if rows is not None:
            values, columns = values[rows], columns[rows]
        return _as_matrix(values, columns, self.size)

    def shared_sensitivity(self, x: np.ndarray, ids: Sequence[int]) -> np.ndarray:
        """The residuals' derivatives with respect to shared parameters ``ids`` at ``x``, shape (N, len(ids))."""
        return _shared_columns(np.asarray(x, dtype=float), self._arrays, np.asarray(ids, dtype=np.int64))


def _as_matrix(values: np.ndarray, columns: np.ndarray, size: int) -> np.ndarray | csr_matrix:
    count, width = values.shape
    if count * size <= 4_000_000:
        return _dense_rows(values, columns, size)
    return csr_matrix((values.ravel(), columns.ravel(), np.arange(0, count * width + 1, width)), shape=(count, size))


@njit(cache=True)
def _dense_rows(values: np.ndarray, columns: np.ndarray, size: int) -> np.ndarray:
    """The matrix (N, size) whose row ``n`` holds ``values[n]`` in the columns ``columns[n]`` (summed if repeated)."""
    matrix = np.zeros((values.shape[0], size))
    for n in range(values.shape[0]):
        for a in range(values.shape[1]):
            matrix[n, columns[n, a]] += values[n, a]
    return matrix


@njit(cache=True)
def _group_sums(matrix: np.ndarray, groups: np.ndarray, count: int) -> np.ndarray:
    """The rows of ``matrix`` (N, P) summed by ``groups`` (N,) in [0, count): shape (count, P)."""
    sums = np.zeros((count, matrix.shape[1]))
    for n in range(matrix.shape[0]):
        for j in range(matrix.shape[1]):
            sums[groups[n], j] += matrix[n, j]
    return sums


def cone_problem(
    setup: Setup,
    points: EdgePoints,
    tips_in_eye: np.ndarray,
    axes: np.ndarray,
    rolls: np.ndarray | None = None,
    *,
    axis: str = "insertion",
    free_tips: bool = True,
    free_shared: Sequence[int] = (),
    shared: np.ndarray | None = None,
    one_frame: bool = True,
) -> ConeProblem:
    """A cone fit in ``setup``'s geometry.

    Parameters
    ----------
    setup : Setup
        The camera, eye and instrument (its edge model, beams and insertion
        point) and how well they are known (:func:`geometry_covariance`).
    points : EdgePoints
    tips_in_eye : ndarray, shape (F, 3)
        Each frame's tip: the start, or the known tip when ``free_tips`` is false.
    axes : ndarray, shape (F, 3)
        Each frame's instrument axis: the start (``free``) or the known axis (``known``).
    rolls : ndarray, shape (F,), optional
        Each frame's starting roll (three beams), radians; default 0.
    axis : str
        ``insertion`` (the axis runs from the insertion point to the tip),
        ``free`` (two angles per frame) or ``known``.
    free_tips : bool
        Fit the tips (else they are known).
    free_shared : sequence of int
        Shared parameters to fit (indices of :data:`spotnav.setup.uncertainty.GEOMETRY_PARAMETERS`).
    shared : ndarray, shape (SHARED_SIZE,), optional
        Start of the shared changes, engine units (default 0: the setup's values).
    one_frame : bool
        The geometry's covariance carries the edge model's error in one frame
        (:func:`geometry_covariance`): false for a fit over many frames.
    """
    if axis not in AXIS_MODES:
        raise ValueError(f"axis must be one of {', '.join(AXIS_MODES)}, got {axis!r}")
    instrument = setup.instrument
    tips = np.ascontiguousarray(tips_in_eye, dtype=float).reshape(-1, 3)
    axes = normalize(np.asarray(axes, dtype=float).reshape(-1, 3))
    count = len(tips)
    if len(axes) != count:
        raise ValueError(f"tips_in_eye and axes must have one row per frame, got {count} and {len(axes)}")
    rolls = np.zeros(count) if rolls is None else np.asarray(rolls, dtype=float).reshape(count)
    frames = _start_frames(tips, axes, rolls)
    free_frame = [0, 1, 2] if free_tips else []
    free_frame += [3, 4] if axis == "free" else []
    free_frame += [5] if instrument.beam_count > 1 else []
    model, base, prior = _setup_arrays(setup, one_frame)
    return ConeProblem(
        model=model,
        base=base,
        beam_count=instrument.beam_count,
        tilt=instrument.beam_tilt,
        points=points,
        frames=frames,
        axis_mode=np.full(count, AXIS_MODES[axis]),
        known_axes=axes,
        shared=np.zeros(SHARED_SIZE) if shared is None else np.asarray(shared, dtype=float),
        free_shared=tuple(int(i) for i in free_shared),
        free_frame=tuple(free_frame),
        prior=prior,
    )


@njit(cache=True)
def _start_frames(tips: np.ndarray, axes: np.ndarray, rolls: np.ndarray) -> np.ndarray:
    """Each frame's start (F, 6) from its tip (F, 3), unit axis (F, 3) and roll (F,): the tip, the axis's rotations
    about y and z (:func:`spotnav.setup.geometry.axis_rotations`), the roll."""
    rotations = _axis_rotations(axes)
    frames = np.empty((len(tips), _FRAME_SIZE))
    for f in range(len(tips)):
        frames[f, 0], frames[f, 1], frames[f, 2] = tips[f, 0], tips[f, 1], tips[f, 2]
        frames[f, 3], frames[f, 4], frames[f, 5] = rotations[f, 0], rotations[f, 1], rolls[f]
    return frames


@lru_cache(maxsize=32)
def _setup_arrays(setup: Setup, one_frame: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a cone problem takes from ``setup`` (once per setup: every tracked frame asks): the camera model
    (:func:`spotnav.optics.camera.camera_model`'s cached array), the base (edge angle, light radius, eye radius,
    insertion point; read-only) and the geometry's covariance (read-only); callers must not modify any of them."""
    instrument = setup.instrument
    base = np.array([edge_angle(setup), instrument.light_radius_mm, setup.eye.radius_mm, *instrument.insertion_in_eye])
    base.setflags(write=False)
    prior = geometry_covariance(setup, one_frame=one_frame)
    return camera_model(setup.camera), base, prior


# --- the compiled model ---------------------------------------------------------------------------------------


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
def _frame_beams(frame: np.ndarray, f: int, shared: np.ndarray, arrays: tuple) -> np.ndarray:
    """The beam axes (B, 3) of one frame's parameters ``frame`` (6,), frame ``f``'s axis mode."""
    base, beam_count, tilt, axis_mode, known_axes = arrays[1], arrays[2], arrays[3], arrays[8], arrays[9]
    insertion = np.empty(3)
    for i in range(3):
        insertion[i] = base[3 + i] + shared[_INSERTION + i]
    axis = np.empty(3)
    axis[0], axis[1], axis[2] = _instrument_axis(frame, axis_mode[f], insertion, known_axes[f])
    return _beam_axes(axis, beam_count, tilt, frame[5])


@njit(cache=True)
def _frame_residuals(
    out: np.ndarray, points: np.ndarray, f: int, frames: np.ndarray, shared: np.ndarray, arrays: tuple
) -> None:
    """Residuals of frame ``f``'s points (written into ``out``) for the values ``shared`` and ``frames``."""
    base, starts, beam_of = arrays[1], arrays[11], arrays[12]
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
def _points_at(shared: np.ndarray, arrays: tuple) -> np.ndarray:
    """The points on the sphere for the shared values (the cached ones when the camera and eye are fixed)."""
    if not arrays[14]:
        return arrays[13]
    model = perturbed_model(arrays[0], shared[_CAMERA:_CAMERA_END])
    return sphere_points(model, arrays[10], arrays[1][_RADIUS] + shared[_RADIUS])


@njit(cache=True)
def _all_residuals(points: np.ndarray, frames: np.ndarray, shared: np.ndarray, arrays: tuple) -> np.ndarray:
    out = np.empty(len(points))
    for f in range(frames.shape[0]):
        _frame_residuals(out, points, f, frames, shared, arrays)
    return out


@njit(cache=True)
def _residuals(x: np.ndarray, arrays: tuple) -> np.ndarray:
    shared, frames = _unpack(x, arrays[4], arrays[5], arrays[6], arrays[7])
    return _all_residuals(_points_at(shared, arrays), frames, shared, arrays)


@njit(cache=True)
def _shared_columns(x: np.ndarray, arrays: tuple, ids: np.ndarray) -> np.ndarray:
    """Each point's derivatives (N, len(ids)) with respect to the shared parameters ``ids``.

    Differentiated through the residual of :func:`_frame_residuals` and the points on the sphere
    (:func:`spotnav.optics.camera.sphere_point_rates`) in one pass over the points; only the beam axes' derivatives with
    respect to the insertion point (per frame, not per point) are central differences.
    """
    shared, frames = _unpack(x, arrays[4], arrays[5], arrays[6], arrays[7])
    base, starts, beam_of = arrays[1], arrays[11], arrays[12]
    points = _points_at(shared, arrays)
    light = base[1] + shared[_LIGHT]
    columns = np.zeros((len(points), len(ids)))
    point_rates = np.zeros((0, 3, 1 + CHANGE_SIZE))
    if np.any((ids >= _RADIUS) & (ids < _CAMERA_END)):
        radius = base[_RADIUS] + shared[_RADIUS]
        point_rates = sphere_point_rates(arrays[0], shared[_CAMERA:_CAMERA_END], arrays[10], radius)
    beam_rates = np.zeros((len(ids), arrays[2], 3))  # d(beam axis) / d(parameter)
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
def _frame_columns(x: np.ndarray, arrays: tuple, per_frame: int) -> tuple[np.ndarray, np.ndarray]:
    """Each point's derivatives with respect to its own frame's ``per_frame`` free parameters, and their columns.

    Differentiated through the residual of :func:`_frame_residuals` in one pass over the points; only the beam
    axes' derivatives (per frame, not per point) are central differences.
    """
    shared, frames = _unpack(x, arrays[4], arrays[5], arrays[6], arrays[7])
    base, frame_index, starts, beam_of = arrays[1], arrays[7], arrays[11], arrays[12]
    points = _points_at(shared, arrays)
    light = base[1] + shared[_LIGHT]
    values = np.zeros((len(points), per_frame))
    columns = np.zeros((len(points), per_frame), dtype=np.int64)
    free = np.empty(per_frame, dtype=np.int64)
    beam_rates = np.empty((per_frame, arrays[2], 3))  # d(beam axis) / d(parameter)
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
def _beam_rate(frame: np.ndarray, f: int, shared: np.ndarray, arrays: tuple, k: int, of_shared: bool) -> np.ndarray:
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
    return (rising - falling) / (2 * step)


# --- the fit ---------------------------------------------------------------------------------------------------


@njit(cache=True)
def robust_sigma(values: np.ndarray, centred: bool) -> float:
    """1.4826 times the median absolute value of ``values`` (N,), less their median if ``centred``.

    The standard deviation of normally distributed values, robust to outliers.
    """
    centre = np.median(values) if centred else 0.0
    return 1.4826 * np.median(np.abs(values - centre))


@njit(cache=True)
def _normal_equations(
    values: np.ndarray, columns: np.ndarray, residuals: np.ndarray, rows: np.ndarray, size: int, scale: float
) -> tuple[np.ndarray, np.ndarray]:
    """``J^T W J`` (P, P) and ``J^T W r`` (P,) over the ``rows`` (K,) of a Jacobian given as rows (N, W) of values
    and columns.

    The weights ``W`` are 1, or with ``scale`` > 0 those of the soft-L1 loss (iteratively reweighted least squares).
    """
    normal, gradient = np.zeros((size, size)), np.zeros(size)
    for n in rows:
        weight = 1.0 if scale <= 0.0 else 1.0 / np.sqrt(1.0 + (residuals[n] / scale) ** 2)
        for a in range(values.shape[1]):
            i = columns[n, a]
            gradient[i] += weight * values[n, a] * residuals[n]
            for b in range(values.shape[1]):
                normal[i, columns[n, b]] += weight * values[n, a] * values[n, b]
    return normal, gradient


@njit(cache=True)
def correlation_inflation(residuals: np.ndarray, groups: np.ndarray) -> float:
    """Variance inflation ``(1 + rho) / (1 - rho)`` for the lag-1 correlation of neighbouring residuals.

    Parameters
    ----------
    residuals : ndarray, shape (N,)
        In order along each contour.
    groups : ndarray, shape (N,), int
        Which contour (0, 1, ...) each residual belongs to (neighbours are taken within one).
    """
    if len(residuals) == 0:
        return 1.0
    sums, counts = np.zeros(groups.max() + 1), np.zeros(groups.max() + 1)
    for n in range(len(residuals)):
        sums[groups[n]] += residuals[n]
        counts[groups[n]] += 1.0
    products, squares = 0.0, 0.0
    for n in range(len(residuals)):
        r = residuals[n] - sums[groups[n]] / counts[groups[n]]
        squares += r * r
        if n > 0 and groups[n] == groups[n - 1]:
            products += r * (residuals[n - 1] - sums[groups[n - 1]] / counts[groups[n - 1]])
    rho = min(max(products / squares, 0.0), 0.9) if squares > 0 else 0.0
    return (1.0 + rho) / (1.0 - rho)


@dataclass(frozen=True)
class FitUncertainty:
    """How well a cone fit knows its free parameters.

    Attributes
    ----------
    covariance : ndarray, shape (P, P)
        The free parameters' covariance: the points' scatter, each spot's
        whole-edge shift, and the fixed geometry's uncertainty.
    data_covariance : ndarray, shape (P, P)
        The same without the fixed geometry's part.
    geometry_gain : ndarray, shape (P, G)
        ``M`` of ``covariance = ... + M C M^T``: a true geometry ``d`` (per
        unit of ``geometry_ids``) away from the assumed one moves the fitted
        parameters by ``M d``.
    geometry_ids : tuple of int
        The fixed shared parameters whose uncertainty the covariance carries.
    """

    covariance: np.ndarray
    data_covariance: np.ndarray
    geometry_gain: np.ndarray
    geometry_ids: tuple[int, ...]


@dataclass(frozen=True)
class ConeSolution:
    """A fitted cone problem.

    Attributes
    ----------
    problem : ConeProblem
    x : ndarray, shape (P,)
        The free parameters.
    shared : ndarray, shape (SHARED_SIZE,)
        The geometry's changes, engine units.
    frames : ndarray, shape (F, 6)
        Each frame's tip, axis angles and roll.
    residuals : ndarray, shape (N,)
        Each point's angle from its cone, radians.
    inliers : ndarray of bool, shape (N,)
        Points the least-squares fit kept.
    uncertainty_of : callable
        Returns the fit's :class:`FitUncertainty`, computed on first use (a
        fit that only leads to another, as a start, never needs it; an error
        computing it is raised there); its parts are this solution's
        properties of the same names.
    settled : bool
        Whether the fit settled inside its box: a tip held at its edge
        (``max_tip_move_mm`` from its start) is a fit the box decided.
    """

    problem: ConeProblem
    x: np.ndarray
    shared: np.ndarray
    frames: np.ndarray
    residuals: np.ndarray
    inliers: np.ndarray
    uncertainty_of: Callable[[], FitUncertainty]
    settled: bool = True

    @cached_property
    def uncertainty(self) -> FitUncertainty:
        """The fit's uncertainty (see :class:`FitUncertainty`), computed once."""
        return self.uncertainty_of()

    @property
    def covariance(self) -> np.ndarray:
        """The free parameters' covariance (P, P), the fixed geometry's part included."""
        return self.uncertainty.covariance

    @property
    def data_covariance(self) -> np.ndarray:
        """The free parameters' covariance (P, P) without the fixed geometry's part."""
        return self.uncertainty.data_covariance

    @property
    def geometry_gain(self) -> np.ndarray:
        """How the fixed geometry moves the free parameters (P, G), see :class:`FitUncertainty`."""
        return self.uncertainty.geometry_gain

    @property
    def geometry_ids(self) -> tuple[int, ...]:
        """The fixed shared parameters whose uncertainty the covariance carries."""
        return self.uncertainty.geometry_ids

    def tip(self, frame: int = 0) -> np.ndarray:
        """Fitted tip of ``frame``, shape (3,), mm."""
        return self.frames[frame, :3].copy()

    @cached_property
    def insertion_in_eye(self) -> np.ndarray:
        """The fitted (or fixed) insertion point, shape (3,), mm (read-only)."""
        point = self.problem.base[3:6] + self.shared[_INSERTION:]
        point.setflags(write=False)
        return point

    def axis(self, frame: int = 0) -> np.ndarray:
        """Fitted instrument axis of ``frame``, unit, shape (3,)."""
        problem = self.problem
        mode = int(problem.axis_mode[frame])
        return np.array(_instrument_axis(self.frames[frame], mode, self.insertion_in_eye, problem.known_axes[frame]))

    def roll(self, frame: int = 0) -> float:
        """Fitted roll of ``frame``, radians (0 for one beam)."""
        return float(self.frames[frame, 5]) if self.problem.beam_count > 1 else 0.0

    def frame_covariance(self, which: Sequence[int], frame: int = 0, *, geometry: bool = True) -> np.ndarray:
        """Covariance of ``frame``'s parameters ``which`` (:data:`FRAME_PARAMETERS` indices), with or without
        the fixed geometry's part; zero for parameters that were not fitted."""
        index = self.problem._arrays[7][frame, list(which)]
        covariance = self.covariance if geometry else self.data_covariance
        fitted = index >= 0
        if fitted.all():
            return covariance[index[:, None], index]
        block = np.zeros((len(index), len(index)))
        block[np.ix_(fitted, fitted)] = covariance[np.ix_(index[fitted], index[fitted])]
        return block

    def tip_covariance(self, frame: int = 0, *, geometry: bool = True) -> np.ndarray:
        """Covariance of ``frame``'s tip, (3, 3), mm^2, with or without the fixed geometry's part."""
        return self.frame_covariance((0, 1, 2), frame, geometry=geometry)

    def tip_sigma_mm(self, frame: int = 0, *, geometry: bool = True) -> float:
        """1-sigma tip uncertainty per axis: the root of a third of the covariance's trace, mm."""
        covariance = self.covariance if geometry else self.data_covariance
        return float(np.sqrt(_free_trace(covariance, self._tip_index(frame)) / 3))

    def tip_terms(self, frame: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """``frame``'s tip covariance from its edge points alone (3, 3), mm^2, and the geometry's gain on its tip
        (3, G): a fixed geometry parameter one unit (engine units, ``geometry_ids`` order) from its assumed value
        moves the tip by its column. The frame's tip must be free."""
        index = self._tip_index(frame)
        if np.any(index < 0):
            raise ValueError(f"frame {frame}'s tip is not free")
        return self.data_covariance[np.ix_(index, index)], self.geometry_gain[index]

    def _tip_index(self, frame: int) -> np.ndarray:
        """Where ``frame``'s tip (3,) is in the free parameters, -1 where fixed."""
        return self.problem._arrays[7][frame, :3]

    def frame_solution(self, frame: int) -> ConeSolution:
        """One frame of a joint fit as a one-frame solution: its points, its block of the covariance.

        The points are seen in the fitted geometry; the block carries the
        shared parameters' uncertainty through its correlations.
        """
        problem = self.problem
        rows = problem.points.frame == frame
        points = problem.points.subset(rows)
        spots, spot = np.unique(points.spot, return_inverse=True)
        sigma = points.spot_sigma[spots]
        one = replace(
            problem,
            points=EdgePoints(points.pixels, np.zeros(len(points.pixels)), points.beam, spot, sigma),
            frames=self.frames[frame : frame + 1],
            axis_mode=problem.axis_mode[frame : frame + 1],
            known_axes=problem.known_axes[frame : frame + 1],
            shared=self.shared,
            free_shared=(),
        )
        index = problem._arrays[7][frame]
        index = index[index >= 0]
        return ConeSolution(
            problem=one,
            x=self.x[index],
            shared=self.shared,
            frames=self.frames[frame : frame + 1],
            residuals=self.residuals[rows],
            inliers=self.inliers[rows],
            uncertainty_of=partial(_block_uncertainty, self, index),
            settled=self.settled,
        )

    def with_edge_shift(self, sigma: float) -> ConeSolution:
        """The same fit, each spot's whole edge, and every spot's together, uncertain by ``sigma`` more (radians,
        added in quadrature).

        Residuals that the points' noise does not explain are a model that
        does not fit the edge: they do not average away over the points, so
        they count as a shift of each spot's whole edge
        (:func:`scatter_covariance`'s ``contour_sigma``) and, since a light
        unlike the setup's moves every spot's edge alike, as that much
        uncertainty of the edge angle (the fixed geometry's prior).

        A joint fit's frame (:meth:`frame_solution`) takes its block of the
        joint fit with every frame's edges so widened (a shared parameter the
        other frames' edges also set comes out more uncertain than it is).
        """
        own = self.uncertainty_of
        if not isinstance(own, partial) or own.func not in (_uncertainty, _block_uncertainty):
            raise TypeError(f"a solution's uncertainty comes from _uncertainty or _block_uncertainty, not {own!r}")
        if own.func is _block_uncertainty:
            joint, index = own.args
            return replace(self, uncertainty_of=partial(_block_uncertainty, joint.with_edge_shift(sigma), index))
        points = self.problem.points
        wider = replace(points, spot_sigma=np.hypot(points.spot_sigma, sigma))
        prior = self.problem.prior.copy()
        prior[_EDGE, _EDGE] += sigma**2
        prior.setflags(write=False)  # as every problem's: one compiled signature
        problem = replace(self.problem, points=wider, prior=prior)
        return replace(self, problem=problem, uncertainty_of=partial(_uncertainty, problem, *own.args[1:]))

    def geometry_share(self, frame: int = 0) -> np.ndarray:
        """Each fixed geometry parameter's share of ``frame``'s tip variance (G,), mm^2, in ``geometry_ids`` order."""
        index = self._tip_index(frame)
        if not self.geometry_ids or np.any(index < 0):
            return np.zeros(len(self.geometry_ids))
        gain = self.geometry_gain[index]
        prior = self.problem.prior[np.ix_(self.geometry_ids, self.geometry_ids)]
        return np.sum(gain * (gain @ prior), axis=0)


@njit(cache=True)
def _free_trace(covariance: np.ndarray, index: np.ndarray) -> float:
    """The sum of ``covariance``'s (P, P) diagonal at the free ones of ``index`` (K,) (those not -1), in order."""
    total = 0.0
    for i in index:
        if i >= 0:
            total += covariance[i, i]
    return total


def _solve(
    problem: ConeProblem,
    x: np.ndarray,
    rows: np.ndarray,
    scale: float | None,
    bounds: tuple[np.ndarray, np.ndarray],
    priors: np.ndarray | None,
) -> np.ndarray:
    """SciPy's trust-region least squares on the points ``rows`` from ``x``; with ``scale``, soft-L1.

    ``priors`` (P,): 1-sigma of a zero-mean Gaussian prior on each free parameter (inf: none), weighed
    against the points at the robust scale of their residuals at ``x``.
    """
    if priors is not None:
        spread = max(robust_sigma(problem.residuals(x)[rows], False), 1e-7)
    weight = None if priors is None else spread / priors
    penalised = None if weight is None else np.isfinite(priors)

    def fun(values: np.ndarray) -> np.ndarray:
        residuals = problem.residuals(values)[rows]
        if weight is None:
            return residuals
        return np.concatenate([residuals, weight[penalised] * values[penalised]])

    def jac(values: np.ndarray) -> np.ndarray | csr_matrix:
        matrix = problem.jacobian_matrix(values, rows)
        if weight is None:
            return matrix
        extra = np.zeros((int(penalised.sum()), problem.size))
        extra[np.arange(len(extra)), np.flatnonzero(penalised)] = weight[penalised]
        return np.vstack([matrix, extra]) if isinstance(matrix, np.ndarray) else _stack_sparse(matrix, extra)

    dense = problem.size * int(np.sum(rows) if rows.dtype == bool else len(rows)) <= 4_000_000
    result = least_squares(
        fun,
        np.clip(x, bounds[0], bounds[1]),
        jac=jac,
        bounds=bounds,
        loss="linear" if scale is None else "soft_l1",
        f_scale=1.0 if scale is None else scale,
        x_scale="jac",
        tr_solver="exact" if dense else "lsmr",
    )
    return result.x


def _stack_sparse(matrix: csr_matrix, extra: np.ndarray) -> csr_matrix:
    return vstack([matrix, csr_matrix(extra)]).tocsr()


@njit(cache=True)
def _gauss_newton(
    x: np.ndarray, arrays: tuple, rows: np.ndarray, scale: float, per_frame: int, steps: int
) -> np.ndarray:
    """``steps`` Gauss-Newton steps from ``x`` on the points ``rows`` (N,), compiled; with ``scale`` > 0 each
    reweighted for the soft-L1 loss. The problem's frame parameters only (no free shared ones)."""
    kept = np.flatnonzero(rows)
    for _ in range(steps):
        residuals = _residuals(x, arrays)
        values, columns = _frame_columns(x, arrays, per_frame)
        normal, gradient = _normal_equations(values, columns, residuals, kept, len(x), scale)
        x = x - np.linalg.solve(normal, gradient)
    return x


_AT_BOX_MM = 1e-6  # a tip this close to its box's wall is held there
_LM_MAX_STEPS = 100
_LM_TRIES = 12  # damping raises per step before the step is given up
_LM_TOLERANCE = 1e-8  # as SciPy's ftol and xtol
_LM_ROBUST_TOLERANCE = 1e-4  # the robust pass only chooses the inliers: the least-squares pass on them settles x
_LM_FIRST_DAMPING = 1e-6  # of the normal matrix's diagonal: a loose direction (one beam's free axis) needs little


@njit(cache=True)
def _robust_cost(residuals: np.ndarray, rows: np.ndarray, scale: float) -> float:
    """Half the sum of squares of ``residuals[rows]``, or with ``scale`` > 0 the soft-L1 loss's (as SciPy's)."""
    cost = 0.0
    for n in range(len(residuals)):
        if rows[n]:
            if scale > 0.0:
                cost += scale * scale * (np.sqrt(1.0 + (residuals[n] / scale) ** 2) - 1.0)
            else:
                cost += 0.5 * residuals[n] ** 2
    return cost


@njit(cache=True)
def _levenberg_marquardt(
    x: np.ndarray,
    arrays: tuple,
    rows: np.ndarray,
    scale: float,
    low: np.ndarray,
    high: np.ndarray,
    per_frame: int,
    tolerance: float,
) -> np.ndarray:
    """Damped Gauss-Newton steps from ``x`` on the points ``rows`` (N,) within the box [low, high], compiled.

    Marquardt's damping scaled by the normal matrix's diagonal (SciPy's
    ``x_scale="jac"``), steps projected onto the box, reweighted for the
    soft-L1 loss when ``scale`` > 0; it stops when a step lowers the cost, or
    moves ``x``, by less than ``tolerance`` of it, or raises the cost by no
    more than that while the model expected no more gain either (MINPACK's
    ``ftol``; damping it further would gain still less). The problem's frame
    parameters only (no free shared ones).
    """
    size = len(x)
    residuals = _residuals(x, arrays)
    cost = _robust_cost(residuals, rows, scale)
    damping = _LM_FIRST_DAMPING
    kept = np.flatnonzero(rows)
    for _ in range(_LM_MAX_STEPS):
        values, columns = _frame_columns(x, arrays, per_frame)
        normal, gradient = _normal_equations(values, columns, residuals, kept, size, scale)
        diagonal = np.maximum(np.diag(normal), 1e-300)
        moved = False
        for _ in range(_LM_TRIES):
            damped = normal + damping * np.diag(diagonal)
            trial = np.minimum(np.maximum(x - np.linalg.solve(damped, gradient), low), high)
            trial_residuals = _residuals(trial, arrays)
            trial_cost = _robust_cost(trial_residuals, rows, scale)
            if trial_cost <= cost:
                moved = True
                break
            step = x - trial
            predicted = step @ gradient - 0.5 * step @ normal @ step  # the gain the quadratic model expected
            if trial_cost - cost <= tolerance * cost and predicted <= tolerance * cost:
                break  # settled, as MINPACK's ftol: the cost rose by at most the tolerance, and more damping gains less
            damping *= 4.0
        if not moved:
            break
        small_step = np.linalg.norm(trial - x) <= tolerance * (tolerance + np.linalg.norm(x))
        small_gain = cost - trial_cost <= tolerance * cost
        x, residuals, cost = trial, trial_residuals, trial_cost
        damping = max(damping / 10.0, 1e-12)
        if small_step or small_gain:
            break
    return x


def fit_cones(
    problem: ConeProblem,
    *,
    solver: str = "trust-region",
    max_tip_move_mm: float = 2.0,
    contour_sigma: float = EDGE_CONTOUR_SIGMA,
    priors: np.ndarray | None = None,
) -> ConeSolution:
    """Fit a cone problem: the one robust recipe (see the module's docstring).

    Parameters
    ----------
    problem : ConeProblem
    solver : str
        ``trust-region`` (SciPy's, for any start and any problem),
        ``levenberg-marquardt`` (compiled damped steps within the box: fast,
        for problems of the frames' own parameters, no priors; a solve that
        ends on the box's wall, as a barely damped first step from a poor
        start can, is done again by SciPy's trust region) or
        ``gauss-newton`` (a few fixed steps, iteratively reweighted: fastest,
        for a start close to the answer, as in tracking; it has no box and
        takes no priors).
    max_tip_move_mm : float
        The tips may not wander further than this from their start: a short arc
        of edge also fits a narrow far cone (with the axis through the
        insertion point, one whose apex sits at that point).
    contour_sigma : float
        Uncertainty of each spot's edge as a whole, radians: a shift of one
        spot's whole edge (texture and vessels under it) that its own points
        cannot show, independent between spots.
    priors : ndarray, shape (P,), optional
        1-sigma of a zero-mean prior on each free parameter (inf: none), in
        the fit and its covariance (``trust-region`` only).
    """
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
    if solver != "trust-region" and (priors is not None or problem.free_shared):
        raise ValueError(f"solver {solver!r} fits the frames' own parameters without priors: use trust-region")
    start = problem.start
    box = _tip_box(start, problem._arrays[7], float(max_tip_move_mm))
    per_frame, code, arrays = len(problem.free_frame), SOLVERS.index(solver), problem._arrays
    done = False
    if solver != "trust-region":
        x, residuals, inliers, done = _fit_recipe(start, arrays, per_frame, box, code, None)
    if not done:  # the same recipe run by Python, whose solve steps may call SciPy
        x, residuals, inliers, _ = _fit_recipe.py_func(start, arrays, per_frame, box, code, (problem, priors))
    return _solution(problem, x, residuals, inliers, contour_sigma, priors, settled=not _at_box(x, box))


@njit(cache=True)
def _tip_box(start: np.ndarray, frame_index: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The box of a fit from ``start`` (P,): the bounds (P,) that keep each free tip coordinate within ``reach`` of
    its start (the other parameters unbounded), and the tips' indices in ``x`` (frame by frame; ``frame_index``
    (F, 6) as :func:`_parameter_index` gives it)."""
    low, high = np.full(len(start), -np.inf), np.full(len(start), np.inf)
    tips = [i for i in frame_index[:, :3].ravel() if i >= 0]
    tip_index = np.array(tips, dtype=np.int64) if tips else np.empty(0, np.int64)
    for i in tip_index:
        low[i], high[i] = start[i] - reach, start[i] + reach
    return low, high, tip_index


@njit(cache=True)
def _at_box(x: np.ndarray, box: tuple) -> bool:
    """Whether a tip of ``x`` is held at its box's wall; ``box`` is (low, high, the tips' indices in ``x``)."""
    low, high, tip_index = box
    for i in tip_index:
        if x[i] - low[i] <= _AT_BOX_MM or high[i] - x[i] <= _AT_BOX_MM:
            return True
    return False


@njit(cache=True)
def _fit_recipe(
    x: np.ndarray, arrays: tuple, per_frame: int, box: tuple, solver: int, context: object
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """The one robust recipe of :func:`fit_cones`: from ``x``, a soft-L1 solve at the residuals' robust scale, the
    points within 3 robust sigmas of the cones, a least-squares solve on them. Returns the parameters, their
    residuals (N,), the inliers (N,) and whether it is done: false when a compiled solve step would need SciPy
    (the rest is then not run).

    Compiled for Gauss-Newton and Levenberg-Marquardt (``context`` None); the trust region, and a
    Levenberg-Marquardt fit whose compiled run was not done, run this same code as ``_fit_recipe.py_func``, whose
    solve steps (:func:`_solve_step`) may call SciPy with ``context`` = (problem, priors).
    """
    residuals = _residuals(x, arrays)
    rows = np.ones(len(residuals), dtype=np.bool_)
    scale = max(robust_sigma(residuals, True), 1e-6)
    x, done = _solve_step(solver, x, arrays, rows, scale, per_frame, box, context)
    if not done:
        return x, residuals, rows, False
    residuals = _residuals(x, arrays)
    inliers = np.abs(residuals) < 3.0 * max(robust_sigma(residuals, False), 1e-7)
    x, done = _solve_step(solver, x, arrays, inliers, 0.0, per_frame, box, context)
    return x, _residuals(x, arrays), inliers, done


def _solve_step(
    solver: int,
    x: np.ndarray,
    arrays: tuple,
    rows: np.ndarray,
    scale: float,
    per_frame: int,
    box: tuple[np.ndarray, np.ndarray, np.ndarray],
    context: tuple[ConeProblem, np.ndarray | None] | None,
) -> tuple[np.ndarray, bool]:
    """One solve of the recipe from ``x`` on the points ``rows`` (N,): soft-L1 at ``scale``, least squares at 0.

    ``solver`` indexes :data:`SOLVERS`; ``box`` is (low, high, the tips' indices) and ``context`` (problem,
    priors), for SciPy. Returns the parameters and whether the step is done (always here, where SciPy can run);
    compiled code calls :func:`_compiled_solve_step` instead.
    """
    if SOLVERS[solver] == "gauss-newton":
        return _gauss_newton(x, arrays, rows, scale, per_frame, 2 if scale > 0.0 else 1), True
    if SOLVERS[solver] == "levenberg-marquardt":
        fitted = _levenberg_marquardt_step(x, arrays, rows, scale, per_frame, box)
        if not _at_box(fitted, box):
            return fitted, True
    (problem, priors), (low, high, _) = context, box
    return _solve(problem, x, rows, None if scale <= 0.0 else scale, (low, high), priors), True


@njit(cache=True)
def _levenberg_marquardt_step(
    x: np.ndarray, arrays: tuple, rows: np.ndarray, scale: float, per_frame: int, box: tuple
) -> np.ndarray:
    """The recipe's Levenberg-Marquardt solve: :func:`_levenberg_marquardt` in ``box`` at the step's tolerance.

    Its first, barely damped steps can leap from a poor start to the box's wall: such a solve is done again by
    SciPy's trust region, which grows its steps only as the model earns it, from the same start.
    """
    tolerance = _LM_ROBUST_TOLERANCE if scale > 0.0 else _LM_TOLERANCE
    return _levenberg_marquardt(x, arrays, rows, scale, box[0], box[1], per_frame, tolerance)


@overload(_solve_step)
def _compiled_solve_step(
    solver: object,
    x: object,
    arrays: object,
    rows: object,
    scale: object,
    per_frame: object,
    box: object,
    context: object,
) -> Callable:
    """:func:`_solve_step` in compiled code: Gauss-Newton's and Levenberg-Marquardt's, not done when the latter
    ends on the box's wall (SciPy's trust region then runs in Python)."""

    def solve_step(  # Numba asks for the overload's own parameters, annotations included
        solver: object,
        x: object,
        arrays: object,
        rows: object,
        scale: object,
        per_frame: object,
        box: object,
        context: object,
    ) -> tuple[np.ndarray, bool]:
        if solver == _GAUSS_NEWTON:
            return _gauss_newton(x, arrays, rows, scale, per_frame, 2 if scale > 0.0 else 1), True
        if solver != _LEVENBERG_MARQUARDT:
            raise ValueError("compiled fits are Gauss-Newton's or Levenberg-Marquardt's")
        fitted = _levenberg_marquardt_step(x, arrays, rows, scale, per_frame, box)
        return fitted, not _at_box(fitted, box)

    return solve_step


@njit(cache=True)
def _scaled_pinv(matrix: np.ndarray) -> np.ndarray:
    """The pseudo-inverse of a symmetric positive semi-definite ``matrix`` (P, P), of its scaled form.

    Columns of very different sizes (a rotation's and k3's differ by 10^10): the matrix scaled to a unit
    diagonal is inverted.
    """
    scale = np.sqrt(np.maximum(np.diag(matrix), 1e-300))
    outer = np.outer(scale, scale)
    return np.linalg.pinv(matrix / outer) / outer


def scatter_covariance(
    jacobian: np.ndarray | csr_matrix,
    residuals: np.ndarray,
    spots: np.ndarray,
    contour_sigma: float | np.ndarray,
    size: int,
    prior_information: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The covariance (P, P) of a least-squares fit's parameters, and their response to the residuals (P, P).

    The points' information ``J^T J / v``, ``v`` the residuals' variance (over
    ``N - size`` degrees of freedom, inflated for the correlation of
    neighbours along each spot, :func:`correlation_inflation`), plus the
    parameters' prior information, inverted; plus the shift of each spot's
    whole edge by ``contour_sigma``, independent between spots. The response
    ``R`` maps ``J^T`` of a change of the residuals to the parameters' change
    (``(J^T J)^-1`` without priors): one spot's shift d moves the parameters by
    ``R J_s^T 1 d``.

    Parameters
    ----------
    jacobian : ndarray or csr_matrix, shape (N, P)
    residuals : ndarray, shape (N,)
    spots : ndarray of int, shape (N,)
        The spot of each point, in order along each spot.
    contour_sigma : float or ndarray
        Radians: one for all spots, or one per spot number (indexed by ``spots``).
    size : int
        Parameters fitted (for the degrees of freedom; at least P).
    prior_information : ndarray, shape (P,), optional
        ``1 / sigma^2`` of each parameter's prior (0: none).
    """
    spots = np.ascontiguousarray(spots, dtype=np.int64)
    labels, which = _spot_labels(spots)
    if isinstance(jacobian, np.ndarray):
        normal = jacobian.T @ jacobian
        sums = _group_sums(jacobian, which, len(labels))  # J_s^T 1 of each spot
    else:
        normal = (jacobian.T @ jacobian).toarray()
        indicator = csr_matrix((np.ones(len(spots)), (which, np.arange(len(spots)))), shape=(len(labels), len(spots)))
        sums = (indicator @ jacobian).toarray()
    given = np.asarray(contour_sigma, dtype=float)
    sigmas = given[labels] if given.ndim else np.full(len(labels), float(given))
    prior = np.zeros(len(normal)) if prior_information is None else np.asarray(prior_information, dtype=float)
    return _covariance_of(normal, np.asarray(residuals, dtype=float), which, sums, sigmas, size, prior)


@njit(cache=True)
def _spot_labels(spots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The spot numbers present in ``spots`` (N,), sorted (S,), and each point's place among them (N,)."""
    counts = np.bincount(spots)
    labels = np.flatnonzero(counts)
    return labels, spots if len(labels) == len(counts) else np.searchsorted(labels, spots)


@njit(cache=True)
def _covariance_of(
    normal: np.ndarray,
    residuals: np.ndarray,
    spots: np.ndarray,
    sums: np.ndarray,
    sigmas: np.ndarray,
    size: int,
    prior_information: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`scatter_covariance` from ``J^T J`` (P, P) and each spot's ``J_s^T 1`` (S, P), spots numbered 0 to
    S - 1 with their ``sigmas`` (S,); compiled."""
    variance = np.sum(residuals**2) / max(len(residuals) - size, 1)
    variance = max(variance * correlation_inflation(residuals, spots), 1e-30)
    covariance = _scaled_pinv(normal / variance + np.diag(prior_information))
    response = covariance / variance
    shifts = (sums @ response) * sigmas.reshape(-1, 1)
    return covariance + shifts.T @ shifts, response


def _solution(
    problem: ConeProblem,
    x: np.ndarray,
    residuals: np.ndarray,
    inliers: np.ndarray,
    contour_sigma: float,
    priors: np.ndarray | None,
    *,
    settled: bool,
) -> ConeSolution:
    """The fit at ``x``, its covariance computed on first use (see :class:`ConeSolution`) from these very values:
    ``x``, ``residuals`` and ``inliers``, the recipe's own new arrays, are made read-only, ``priors`` copied."""
    priors = None if priors is None else np.array(priors, dtype=float)
    for values in (x, residuals, inliers, priors):
        if values is not None:
            values.setflags(write=False)
    shared, frames = problem.unpack(x)
    shared.setflags(write=False)  # insertion_in_eye, kept, is computed from them
    frames.setflags(write=False)
    uncertainty_of = partial(_uncertainty, problem, x, residuals, inliers, contour_sigma, priors)
    return ConeSolution(problem, x, shared, frames, residuals, inliers, uncertainty_of, settled)


def _block_uncertainty(solution: ConeSolution, index: np.ndarray) -> FitUncertainty:
    """The uncertainty of the free parameters ``index`` of a fit: their block of its covariance."""
    whole = solution.uncertainty
    return FitUncertainty(
        whole.covariance[np.ix_(index, index)],
        whole.data_covariance[np.ix_(index, index)],
        whole.geometry_gain[index],
        whole.geometry_ids,
    )


def _uncertainty(
    problem: ConeProblem,
    x: np.ndarray,
    residuals: np.ndarray,
    inliers: np.ndarray,
    contour_sigma: float,
    priors: np.ndarray | None,
) -> FitUncertainty:
    """The uncertainty of the fit at ``x`` (see :class:`FitUncertainty`)."""
    information = None if priors is None else 1.0 / np.asarray(priors, dtype=float) ** 2
    points = problem.points
    if not problem.free_shared and len(problem.frames) == 1:  # one frame's own parameters: one compiled call
        covariance, data, gain, ids = _frame_uncertainty(
            x,
            problem._arrays,
            len(problem.free_frame),
            inliers,
            residuals,
            points.spot,
            np.hypot(contour_sigma, points.spot_sigma),
            np.zeros(problem.size) if information is None else information,
            problem.prior,
        )
        return FitUncertainty(covariance, data, gain, tuple(ids.tolist()))
    spots = points.spot[inliers]
    sigmas = np.hypot(contour_sigma, points.spot_sigma)
    uncertain = np.flatnonzero(np.diag(problem.prior) > 0)
    geometry_ids = tuple(int(i) for i in uncertain if i not in problem.free_shared)
    jacobian = problem.jacobian_matrix(x, inliers)
    data, response = scatter_covariance(jacobian, residuals[inliers], spots, sigmas, problem.size, information)
    gain = np.zeros((problem.size, len(geometry_ids)))
    covariance = data
    if geometry_ids:
        sensitivity = problem.shared_sensitivity(x, geometry_ids)[inliers]
        gain = response @ np.asarray(jacobian.T @ sensitivity)
        covariance = data + gain @ problem.prior[np.ix_(geometry_ids, geometry_ids)] @ gain.T
    return FitUncertainty(covariance, data, gain, geometry_ids)


@njit(cache=True)
def _frame_uncertainty(
    x: np.ndarray,
    arrays: tuple,
    per_frame: int,
    inliers: np.ndarray,
    residuals: np.ndarray,
    spots: np.ndarray,
    sigmas: np.ndarray,
    information: np.ndarray,
    prior: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_uncertainty` of a one-frame fit of its own parameters, compiled: the covariance, the data's
    covariance, the geometry's gain and the fixed shared parameters it carries (those with uncertainty).

    ``spots`` (N,) each point's spot and ``sigmas`` (at least max(spots) + 1,) each spot number's own
    sigma, as :func:`scatter_covariance`'s; ``information`` (P,) the parameters' prior information;
    ``prior`` (SHARED_SIZE, SHARED_SIZE) the geometry's covariance. Every shared parameter is fixed (no free
    shared parameters: the caller's condition), so every one with uncertainty is carried.
    """
    values, columns = _frame_columns(x, arrays, per_frame)
    kept = np.flatnonzero(inliers)
    jacobian = _dense_rows(values[kept], columns[kept], per_frame)
    labels, which = _spot_labels(spots[kept])
    sums = _group_sums(jacobian, which, len(labels))
    normal = jacobian.T @ jacobian
    data, response = _covariance_of(normal, residuals[kept], which, sums, sigmas[labels], per_frame, information)
    ids = np.flatnonzero(np.diag(prior) > 0)
    if len(ids) == 0:
        return data, data, np.zeros((per_frame, 0)), ids
    block = np.empty((len(ids), len(ids)))
    for i in range(len(ids)):
        for j in range(len(ids)):
            block[i, j] = prior[ids[i], ids[j]]
    gain = response @ (jacobian.T @ _shared_columns(x, arrays, ids)[kept])
    return data + gain @ block @ gain.T, data, gain, ids
