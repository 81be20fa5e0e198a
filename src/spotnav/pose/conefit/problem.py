"""A cone fit's problem: the edge points, the geometry they are seen in, the start, and what is free.

:class:`EdgePoints` says which spot, beam and frame each edge point came from; :func:`cone_problem` builds a
:class:`ConeProblem` from a setup, which holds the data as the compiled model reads it
(:class:`~spotnav.pose.conefit.model.ConeArrays`) and gives the residuals and their Jacobian at any free parameters.
Every precise estimate in spotnav is such a problem: localizing a frame, tracking it, calibrating the geometry from
known poses and fitting the eye's radius over a sequence differ only in which parameters are free.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numba import njit
from scipy.sparse import csr_matrix

from spotnav.optics.camera import camera_model, perturbed_model, sphere_points
from spotnav.optics.light import edge_angle
from spotnav.pose.conefit.model import ConeArrays, _dense_rows, _frame_columns, _residuals, _shared_columns, _unpack
from spotnav.pose.conefit.parameters import (
    _CAMERA,
    _CAMERA_END,
    _FRAME_SIZE,
    _RADIUS,
    AXIS_MODES,
    SHARED_SIZE,
    geometry_covariance,
)
from spotnav.setup.config import Setup
from spotnav.setup.geometry import _axis_rotations, normalize

__all__ = ["ConeProblem", "EdgePoints", "cone_problem"]


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
        :data:`~spotnav.pose.conefit.parameters.AXIS_MODES`: through the insertion point, free, or known.
    known_axes : ndarray, shape (F, 3)
        The known axes (used where the mode is ``known``).
    shared : ndarray, shape (SHARED_SIZE,)
        Start (or fixed value) of the geometry's changes, engine units.
    free_shared : tuple of int
        Shared parameters to fit.
    free_frame : tuple of int
        Per-frame parameters to fit (indices of
        :data:`~spotnav.pose.conefit.parameters.FRAME_PARAMETERS`), the same for every frame.
    prior : ndarray, shape (SHARED_SIZE, SHARED_SIZE)
        The geometry's covariance (:func:`~spotnav.pose.conefit.parameters.geometry_covariance`): what the fixed
        shared parameters add to the fit's covariance.
    arrays : ConeArrays
        All of it as the compiled kernels read it (:mod:`spotnav.pose.conefit.model`), computed on creation.
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
    arrays: ConeArrays = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        frames = np.ascontiguousarray(self.frames, dtype=float).reshape(-1, _FRAME_SIZE)
        count = len(frames)
        shared_index, frame_index = _parameter_index(self.free_shared, self.free_frame, count)
        starts = _frame_starts(self.points.frame, count)
        camera_free = any(_RADIUS <= i < _CAMERA_END for i in self.free_shared)
        model = perturbed_model(self.model, self.shared[_CAMERA:_CAMERA_END])
        cached = sphere_points(model, self.points.pixels, self.base[_RADIUS] + self.shared[_RADIUS])
        arrays = ConeArrays(
            model=np.ascontiguousarray(self.model, dtype=float),
            base=np.ascontiguousarray(self.base, dtype=float),
            beam_count=int(self.beam_count),
            tilt=float(self.tilt),
            shared=np.array(self.shared, dtype=float),  # writable, as a solution's is not: one compiled kernel
            shared_index=shared_index,
            frames=frames,
            frame_index=frame_index,
            axis_mode=np.ascontiguousarray(self.axis_mode, dtype=np.int64),
            known_axes=np.ascontiguousarray(self.known_axes, dtype=float).reshape(-1, 3),
            pixels=self.points.pixels,
            starts=starts,
            beam=self.points.beam,
            points_in_eye=cached,
            camera_free=camera_free,
        )
        object.__setattr__(self, "frames", frames)
        object.__setattr__(self, "arrays", arrays)

    @property
    def size(self) -> int:
        """Number of free parameters."""
        return len(self.free_shared) + len(self.free_frame) * len(self.frames)

    @property
    def points_in_eye(self) -> np.ndarray:
        """The points on the retina at the start's camera and eye radius, shape (N, 3), mm (NaN off the bowl)."""
        return self.arrays.points_in_eye

    @property
    def start(self) -> np.ndarray:
        """The free parameters' start, shape (size,)."""
        frame_index = self.arrays.frame_index
        x = np.empty(self.size)
        if self.free_shared:
            x[: len(self.free_shared)] = self.shared[list(self.free_shared)]
        free = frame_index >= 0
        x[frame_index[free]] = self.frames[free]
        return x

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The shared (SHARED_SIZE,) and per-frame (F, 6) values at the free parameters ``x``."""
        arrays = self.arrays
        return _unpack(
            np.asarray(x, dtype=float), arrays.shared, arrays.shared_index, arrays.frames, arrays.frame_index
        )

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Each point's angle from its edge cone at ``x``, radians, shape (N,)."""
        return _residuals(np.asarray(x, dtype=float), self.arrays)

    def jacobian(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The residuals' Jacobian at ``x`` as rows of ``(values, columns)``, each shape (N, W).

        Row ``n`` has its nonzero entries ``values[n]`` in the columns
        ``columns[n]``: the free shared parameters, then its frame's own.
        """
        x = np.asarray(x, dtype=float)
        values, columns = _frame_columns(x, self.arrays, len(self.free_frame))
        if not self.free_shared:
            return values, columns
        shared_ids = np.array(self.free_shared, dtype=np.int64)
        shared_columns = _shared_columns(x, self.arrays, shared_ids)
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
        return _shared_columns(np.asarray(x, dtype=float), self.arrays, np.asarray(ids, dtype=np.int64))


def _as_matrix(values: np.ndarray, columns: np.ndarray, size: int) -> np.ndarray | csr_matrix:
    count, width = values.shape
    if count * size <= 4_000_000:
        return _dense_rows(values, columns, size)
    return csr_matrix((values.ravel(), columns.ravel(), np.arange(0, count * width + 1, width)), shape=(count, size))


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
        point) and how well they are known (:func:`~spotnav.pose.conefit.parameters.geometry_covariance`).
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
        (:func:`~spotnav.pose.conefit.parameters.geometry_covariance`): false for a fit over many frames.
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
