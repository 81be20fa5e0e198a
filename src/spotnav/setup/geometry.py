"""Geometry of light cones, the retina sphere and the instrument (thesis 4.1-4.2).

All lengths are in mm and all angles in radians. Points and directions are NumPy
arrays whose last axis has length 3; unless a name says otherwise they are in
the eye frame (see ``docs/conventions.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = [
    "ApproximationDeviation",
    "BeamAssignment",
    "InstrumentPose",
    "angles_between",
    "approximation_deviation",
    "assign_beams",
    "axis_rotations",
    "beam_axes",
    "cone_generators",
    "cone_sphere_curve",
    "cone_sphere_points",
    "edge_angle_of_blend",
    "instrument_to_eye",
    "intersect_rays_sphere",
    "normalize",
    "orthonormal_basis",
    "rotation_about_y",
    "rotation_about_z",
    "spot_attenuation",
]


def normalize(vectors: np.ndarray) -> np.ndarray:
    """Unit vectors along ``vectors``, shape (..., 3).

    Raises
    ------
    ValueError
        If the last axis is not of length 3, or any vector has zero or non-finite length.
    """
    vectors = np.asarray(vectors, dtype=float)
    if vectors.shape[-1:] != (3,):
        raise ValueError(f"vectors must have shape (..., 3), got {vectors.shape}")
    units, finite = _unit_rows(np.ascontiguousarray(vectors).reshape(-1, 3))
    if not finite:
        raise ValueError("cannot normalize a zero or non-finite vector")
    return units.reshape(vectors.shape)


@njit(cache=True, error_model="numpy")
def _unit_rows(rows: np.ndarray) -> tuple[np.ndarray, bool]:
    """:func:`normalize` of rows (N, 3), compiled (NumPy's sum of the squares, in its order: the same bits), and
    whether every row had a finite, nonzero length."""
    units = np.empty_like(rows)
    finite = True
    for n in range(len(rows)):
        norm = np.sqrt(rows[n, 0] * rows[n, 0] + rows[n, 1] * rows[n, 1] + rows[n, 2] * rows[n, 2])
        finite = finite and 0.0 < norm < np.inf  # NaN fails both
        for k in range(3):
            units[n, k] = rows[n, k] / norm
    return units, finite


@njit(cache=True)
def rotation_about_z(angle: float) -> np.ndarray:
    """Right-handed rotation matrix about +z by ``angle`` radians, shape (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@njit(cache=True)
def rotation_about_y(angle: float) -> np.ndarray:
    """Right-handed rotation matrix about +y by ``angle`` radians, shape (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def orthonormal_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``(e1, e2)`` completing ``axis`` to a right-handed frame.

    ``e1`` is the projection of eye ``+x`` on the plane normal to ``axis`` (eye
    ``+y`` when that projection vanishes), the contract's zero roll, and
    ``e2 = axis x e1``. The projection counts as vanished within 1e-6 rad of
    ``+-x``, where its direction is lost to rounding.

    Parameters
    ----------
    axis : ndarray, shape (..., 3)
        Unit vector(s).

    Returns
    -------
    e1, e2 : ndarray, shape (..., 3)
    """
    axis = normalize(axis)
    bases = _orthonormal_bases(np.ascontiguousarray(axis.reshape(-1, 3)))
    return bases[:, 0].reshape(axis.shape), bases[:, 1].reshape(axis.shape)


@njit(cache=True)
def _orthonormal_bases(axes: np.ndarray) -> np.ndarray:
    """``e1`` and ``e2`` (M, 2, 3) of :func:`orthonormal_basis` for unit ``axes`` (M, 3)."""
    bases = np.empty((len(axes), 2, 3))
    for m in range(len(axes)):
        basis = _basis(axes[m])
        for k in range(2):
            for i in range(3):
                bases[m, k, i] = basis[k, i]
    return bases


@njit(cache=True)
def _basis(axis: np.ndarray) -> np.ndarray:
    """``e1`` and ``e2`` (2, 3) of :func:`orthonormal_basis` for one unit ``axis`` (3,); compiled."""
    x, y, z = axis[0], axis[1], axis[2]
    a, b, c = 1.0 - x * x, -x * y, -x * z  # +x less its part along the axis
    if np.sqrt(a * a + b * b + c * c) < 1e-6:
        a, b, c = -y * x, 1.0 - y * y, -y * z  # +y instead
    norm = np.sqrt(a * a + b * b + c * c)
    a, b, c = a / norm, b / norm, c / norm
    along = a * x + b * y + c * z  # remove what rounding left along the axis
    a, b, c = a - along * x, b - along * y, c - along * z
    norm = np.sqrt(a * a + b * b + c * c)
    a, b, c = a / norm, b / norm, c / norm
    basis = np.empty((2, 3))
    basis[0, 0], basis[0, 1], basis[0, 2] = a, b, c
    basis[1, 0], basis[1, 1], basis[1, 2] = y * c - z * b, z * a - x * c, x * b - y * a
    return basis


def cone_generators(axis: np.ndarray, half_angle: float, azimuths: np.ndarray) -> np.ndarray:
    """Unit directions of a cone's surface lines.

    Parameters
    ----------
    axis : ndarray, shape (3,)
        Cone axis (unit vector).
    half_angle : float
        Angle between the axis and each surface line, radians.
    azimuths : ndarray, shape (N,)
        Angles around the axis, from ``e1`` of :func:`orthonormal_basis` toward ``e2``.

    Returns
    -------
    ndarray, shape (N, 3)
    """
    axis = normalize(axis)
    e1, e2 = orthonormal_basis(axis)
    azimuths = np.asarray(azimuths, dtype=float)[:, None]
    radial = np.cos(azimuths) * e1 + np.sin(azimuths) * e2
    generators: np.ndarray = np.cos(half_angle) * axis + np.sin(half_angle) * radial
    return generators


def intersect_rays_sphere(
    origins: np.ndarray,
    directions: np.ndarray,
    center: np.ndarray,
    radius: float,
    *,
    far: bool = True,
) -> np.ndarray:
    """Ray parameter of the ray-sphere intersection (the general form of Eq. 4.1).

    Solves ``|o + t d - c| = r`` for ``t``.

    Parameters
    ----------
    origins : ndarray, shape (..., 3)
    directions : ndarray, shape (..., 3)
        Unit ray directions.
    center : ndarray, shape (3,)
    radius : float
    far : bool
        Take the larger root (a camera outside the sphere sees the bowl from
        inside through its far wall; a source inside the sphere has one
        positive root, the larger).

    Returns
    -------
    ndarray, shape (...)
        ``t``, NaN where the ray misses the sphere.
    """
    oc = np.asarray(origins, dtype=float) - np.asarray(center, dtype=float)
    directions = np.asarray(directions, dtype=float)
    half_b = np.sum(oc * directions, axis=-1)
    c = np.sum(oc * oc, axis=-1) - radius * radius
    disc = half_b * half_b - c
    root = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
    t: np.ndarray = -half_b + root if far else -half_b - root
    return t


def cone_sphere_curve(
    apex: np.ndarray,
    axis: np.ndarray,
    half_angle: float,
    center: np.ndarray,
    radius: float,
    count: int = 360,
) -> np.ndarray:
    """Exact intersection curve of a cone (apex inside the sphere) with the sphere.

    Parameters
    ----------
    apex, axis : ndarray, shape (3,)
        Cone apex and unit axis.
    half_angle : float
        Cone half-angle, radians.
    center : ndarray, shape (3,)
    radius : float
    count : int
        Number of points, evenly spaced in azimuth.

    Returns
    -------
    ndarray, shape (count, 3)

    Raises
    ------
    ValueError
        If the apex is not strictly inside the sphere.
    """
    apex, center = np.asarray(apex, float), np.asarray(center, float)
    if np.linalg.norm(apex - center) >= radius:
        raise ValueError("apex must lie strictly inside the sphere")
    return cone_sphere_points(apex, normalize(axis), float(half_angle), center, float(radius), int(count))


@njit(cache=True)
def cone_sphere_points(
    apex: np.ndarray, axis: np.ndarray, half_angle: float, center: np.ndarray, radius: float, count: int
) -> np.ndarray:
    """:func:`cone_sphere_curve` for a unit ``axis`` and an apex inside the sphere, compiled (tracking draws
    each beam's curve every frame): the generators of :func:`cone_generators` met by the sphere, far root."""
    basis = _basis(axis)
    points = np.empty((count, 3))
    cos_half, sin_half = np.cos(half_angle), np.sin(half_angle)
    for n in range(count):
        azimuth = 2.0 * np.pi * n / count
        ray = cos_half * axis + sin_half * (np.cos(azimuth) * basis[0] + np.sin(azimuth) * basis[1])
        offset = apex - center
        half_b = np.sum(offset * ray)
        root = np.sqrt(half_b * half_b - (np.sum(offset * offset) - radius * radius))
        points[n] = apex + (root - half_b) * ray
    return points


def beam_axes(axis: np.ndarray, beam_count: int, tilt: float, roll: float | np.ndarray = 0.0) -> np.ndarray:
    """Beam axes of the instrument, contract's roll convention.

    One beam shares the instrument axis. Several beams tilt by ``tilt`` from it,
    beam 0 toward ``e1`` of :func:`orthonormal_basis` turned by ``roll``, beam
    ``k`` at ``k * 360 / beam_count`` degrees further (three beams: +120 and
    +240); turns are counter-clockwise seen from the tip looking along the axis.
    The contract's zero roll is ``roll = 0``.

    Parameters
    ----------
    axis : ndarray, shape (..., 3)
        Instrument axis (or axes).
    beam_count : int
    tilt : float
        Radians.
    roll : float or ndarray, shape (...)
        Radians.

    Returns
    -------
    ndarray, shape (..., beam_count, 3)
    """
    axis = normalize(axis)
    if beam_count == 1:
        return axis[..., None, :]
    shape = np.broadcast_shapes(axis.shape[:-1], np.shape(roll))
    axes = np.ascontiguousarray(np.broadcast_to(axis, (*shape, 3)).reshape(-1, 3))
    rolls = np.ascontiguousarray(np.broadcast_to(np.asarray(roll, dtype=float), shape).reshape(-1))
    return _beam_axes_of_rows(axes, beam_count, tilt, rolls).reshape(*shape, beam_count, 3)


@njit(cache=True)
def _beam_axes_of_rows(axes: np.ndarray, beam_count: int, tilt: float, rolls: np.ndarray) -> np.ndarray:
    """Beam axes (M, beam_count, 3) of unit ``axes`` (M, 3) with ``rolls`` (M,)."""
    beams = np.empty((len(axes), beam_count, 3))
    for m in range(len(axes)):
        beams_of_axis = _beam_axes(axes[m], beam_count, tilt, rolls[m])
        for beam in range(beam_count):
            for i in range(3):
                beams[m, beam, i] = beams_of_axis[beam, i]
    return beams


@njit(cache=True)
def _beam_axes(axis: np.ndarray, beam_count: int, tilt: float, roll: float) -> np.ndarray:
    """Beam axes (beam_count, 3) of :func:`beam_axes` for one unit ``axis`` (3,); compiled."""
    beams = np.empty((beam_count, 3))
    if beam_count == 1:
        beams[0, 0], beams[0, 1], beams[0, 2] = axis[0], axis[1], axis[2]
        return beams
    basis = _basis(axis)
    for beam in range(beam_count):
        # Counter-clockwise seen looking along the axis is a positive turn about -axis.
        azimuth = -(roll + 2.0 * np.pi * beam / beam_count)
        for i in range(3):
            radial = np.cos(azimuth) * basis[0, i] + np.sin(azimuth) * basis[1, i]
            beams[beam, i] = np.cos(tilt) * axis[i] + np.sin(tilt) * radial
    return beams


@dataclass(frozen=True)
class BeamAssignment:
    """Which of three beams made each spot (:func:`assign_beams`), or why that cannot be told.

    Attributes
    ----------
    status : str
        ``"ok"``, or ``"ambiguous"`` when two directions get one beam.
    beams : tuple of int
        Beam index per direction, the first beam 0 (empty when ambiguous).
    roll : float
        The roll of :func:`beam_axes` that puts beam 0 on the first direction, radians (NaN when ambiguous).
    """

    status: str
    beams: tuple[int, ...] = ()
    roll: float = float("nan")

    @property
    def ok(self) -> bool:
        """Whether each direction has its own beam."""
        return self.status == "ok"


def assign_beams(directions: np.ndarray, axis: np.ndarray) -> BeamAssignment:
    """Which of three beams points along each direction, and the roll that puts beam 0 on the first.

    Parameters
    ----------
    directions : ndarray, shape (n, 3), n <= 3
        Directions from the tip toward each spot (or each spot's beam axis).
    axis : ndarray, shape (3,)
        The instrument axis.

    Returns
    -------
    BeamAssignment
        Beam index per direction (the first is beam 0) and the roll of :func:`beam_axes`, radians; ``ambiguous``
        when two directions get one beam.
    """
    e1, e2 = orthonormal_basis(axis)
    azimuths = np.arctan2(directions @ e2, directions @ e1)
    step = 2.0 * np.pi / 3.0  # beam j sits at azimuth -(roll + j step)
    beams = tuple(int(np.round(((azimuths[0] - a) % (2.0 * np.pi)) / step)) % 3 for a in azimuths)
    if len(set(beams)) < len(beams):
        return BeamAssignment("ambiguous")
    return BeamAssignment("ok", beams, float(-azimuths[0]))


def spot_attenuation(cos_angle: np.ndarray, half_angle: float, blend: float) -> np.ndarray:
    """Cycles' spot attenuation: 0 outside the cone, a smoothstep in cosine space over the blend.

    Parameters
    ----------
    cos_angle : ndarray
        Cosine of the angle between the beam axis and the direction to the point.
    half_angle : float
        Cone half-angle, radians.
    blend : float
        Blender's ``spot_blend`` in [0, 1].
    """
    cos_edge = np.cos(half_angle)
    if blend == 0.0:
        inside: np.ndarray = (cos_angle > cos_edge).astype(float)
        return inside
    t = np.clip((cos_angle - cos_edge) / ((1.0 - cos_edge) * blend), 0.0, 1.0)
    smoothstep: np.ndarray = t * t * (3.0 - 2.0 * t)
    return smoothstep


def edge_angle_of_blend(half_angle: float, blend: float) -> float:
    """Angle from the beam axis where a Cycles spot's light is half of its full value, radians.

    The midpoint of the smoothstep in cosine space: where an edge detector that
    takes the level halfway between the local plateau and background puts the
    spot's edge. A sharp edge (``blend = 0``) gives ``half_angle``.
    """
    cos_edge = np.cos(half_angle)
    return float(np.arccos(cos_edge + 0.5 * blend * (1.0 - cos_edge)))


def axis_rotations(axes: np.ndarray) -> np.ndarray:
    """The instrument axis as a rotation about ``y`` then about ``z`` (thesis 6.4, Table 6.10).

    ``axis = Rz(about_z) @ Ry(about_y) @ (0, 0, -1)`` with ``about_y`` in
    ``[0, pi]`` (the tilt from straight down) and ``about_z`` in ``(-pi, pi]``
    (the direction of the tilt).

    Parameters
    ----------
    axes : ndarray, shape (..., 3)
        Unit axes.

    Returns
    -------
    ndarray, shape (..., 2)
        ``(about_y, about_z)``, radians.
    """
    axes = normalize(np.asarray(axes, dtype=float))
    return _axis_rotations(np.ascontiguousarray(axes.reshape(-1, 3))).reshape(*axes.shape[:-1], 2)


@njit(cache=True)
def _axis_rotations(axes: np.ndarray) -> np.ndarray:
    """:func:`axis_rotations` of unit axes (N, 3), compiled."""
    rotations = np.empty((len(axes), 2))
    for n in range(len(axes)):
        rotations[n, 0] = np.arccos(min(max(-axes[n, 2], -1.0), 1.0))
        rotations[n, 1] = np.arctan2(-axes[n, 1], -axes[n, 0])
    return rotations


def angles_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between directions, shape of the broadcast leading axes, radians (robust near 0)."""
    a, b = normalize(np.asarray(a, dtype=float)), normalize(np.asarray(b, dtype=float))
    angles: np.ndarray = np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))
    return angles


@dataclass(frozen=True)
class InstrumentPose:
    """Tip position and instrument axis in the eye frame.

    Attributes
    ----------
    tip_in_eye : ndarray, shape (3,)
        Tip (apex of every cone), mm.
    axis : ndarray, shape (3,)
        Unit vector from the insertion point toward the tip.
    """

    tip_in_eye: np.ndarray
    axis: np.ndarray

    def __post_init__(self) -> None:
        tip = np.asarray(self.tip_in_eye, dtype=float).reshape(-1)
        if tip.shape != (3,) or not np.all(np.isfinite(tip)):
            raise ValueError(f"tip must be 3 finite numbers, got {self.tip_in_eye!r}")
        axis = np.asarray(self.axis, dtype=float).reshape(-1)
        if axis.shape != (3,) or not np.all(np.isfinite(axis)) or np.linalg.norm(axis) == 0:
            raise ValueError(f"axis must be 3 finite numbers, not all zero, got {self.axis!r}")
        object.__setattr__(self, "tip_in_eye", tip)
        object.__setattr__(self, "axis", normalize(axis))

    @classmethod
    def through_insertion(cls, tip_in_eye: np.ndarray, insertion_in_eye: np.ndarray) -> InstrumentPose:
        """Pose whose axis runs from the insertion point to the tip."""
        tip = np.asarray(tip_in_eye, dtype=float)
        return cls(tip, tip - np.asarray(insertion_in_eye, dtype=float))


def instrument_to_eye(tip_in_eye: np.ndarray, axis: np.ndarray, roll: float = 0.0) -> np.ndarray:
    """Homogeneous transform from the instrument's frame to the eye frame, shape (4, 4), mm.

    The instrument's frame has its origin at the tip, ``+z`` along the axis
    (toward the retina) and ``+x`` toward beam 0 (``e1`` of
    :func:`orthonormal_basis` turned by ``roll``, the contract's roll
    convention); ``+y = z x x``.
    """
    axis = normalize(axis)
    # Beam 0 leans toward the radial direction at azimuth -roll (see beam_axes).
    e1, e2 = orthonormal_basis(axis)
    x_axis = np.cos(roll) * e1 - np.sin(roll) * e2
    transform = np.eye(4)
    transform[:3, 0], transform[:3, 1], transform[:3, 2] = x_axis, np.cross(axis, x_axis), axis
    transform[:3, 3] = tip_in_eye
    return transform


@dataclass(frozen=True)
class ApproximationDeviation:
    """How far the planar ellipse of thesis 4.2 is from the true cone-sphere curve.

    All in micrometres.

    Attributes
    ----------
    gap_y_um : float
        Largest gap in ``y`` between the curves at equal ``x`` (Eq. 4.10 vs
        Eq. 4.19): Table 4.1's "difference".
    to_plane_um : float
        Largest distance from the true curve to the plane through A and B.
    along_ray_um : float
        Largest distance between the curves along the same cone line.
    """

    gap_y_um: float
    to_plane_um: float
    along_ray_um: float


def approximation_deviation(
    half_angle: float,
    sphere_center_in_cone: tuple[float, float] = (3.7, -6.35),
    radius: float = 12.5,
    samples: int = 200001,
) -> ApproximationDeviation:
    """Deviation of the cone-plane ellipse from the cone-sphere curve (Table 4.1).

    Cone frame: apex at the origin, axis ``+z``; the sphere's centre is
    ``(x0, 0, z0)`` (Table 4.2, whose "y_0" is ``z0``; thesis-notes 4).

    Parameters
    ----------
    half_angle : float
        Cone half-angle beta, radians.
    sphere_center_in_cone : (x0, z0)
    radius : float
    samples : int
        Samples of ``x`` over ``[x2, x1]`` and of the azimuth.
    """
    x0, z0 = sphere_center_in_cone
    c = np.tan(half_angle)
    k = 1.0 + 1.0 / c**2
    const = x0**2 + z0**2 - radius**2
    # Eq. 4.12 and 4.13 (the printed discriminants are garbled; these are exact).
    x1 = (2 * (x0 + z0 / c) + np.sqrt((2 * x0 + 2 * z0 / c) ** 2 - 4 * k * const)) / (2 * k)
    x2 = (2 * (x0 - z0 / c) - np.sqrt((2 * x0 - 2 * z0 / c) ** 2 - 4 * k * const)) / (2 * k)
    z1, z2 = x1 / c, -x2 / c  # Eq. 4.14, 4.15
    slope = (z1 - z2) / (c * (z1 + z2))  # Eq. 4.18
    offset = z1 - x1 * slope

    x = np.linspace(x2, x1, samples)
    # Eq. 4.9 and 4.10: the cone-sphere curve.
    disc = 4 * z0**2 - 4 * (1 + c**2) * (const - 2 * x0 * x)
    z_sphere = (2 * z0 + np.sqrt(np.maximum(disc, 0.0))) / (2 * (1 + c**2))
    y_sphere = np.sqrt(np.maximum(z_sphere**2 * c**2 - x**2, 0.0))
    # Eq. 4.19: the cone-plane ellipse.
    y_plane = np.sqrt(np.maximum((slope * x + offset) ** 2 * c**2 - x**2, 0.0))
    gap_y = np.max(np.abs(y_sphere - y_plane))
    to_plane = np.max(np.abs(z_sphere - (slope * x + offset))) / np.hypot(1.0, slope)

    azimuth = np.linspace(0.0, 2.0 * np.pi, samples)
    rays = np.stack(
        [
            np.sin(half_angle) * np.cos(azimuth),
            np.sin(half_angle) * np.sin(azimuth),
            np.full_like(azimuth, np.cos(half_angle)),
        ],
        axis=-1,
    )
    t_sphere = intersect_rays_sphere(np.zeros(3), rays, np.array([x0, 0.0, z0]), radius)
    t_plane = offset / (rays[:, 2] - slope * rays[:, 0])
    along_ray = np.max(np.abs(t_sphere - t_plane))
    return ApproximationDeviation(
        gap_y_um=1000.0 * float(gap_y),
        to_plane_um=1000.0 * float(to_plane),
        along_ray_um=1000.0 * float(along_ray),
    )
