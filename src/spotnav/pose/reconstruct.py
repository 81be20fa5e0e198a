"""From a spot's contour to the cone's apex: the thesis's ellipse method (section 4.4).

The thesis's (4.4, Algorithm 1), :func:`apex_candidates`: the contour is
back-projected onto the retina sphere, moved to the origin, rotated about ``z``
then ``y`` so that the sphere's tangent plane at its centre becomes the ``xy``
plane, and fitted with an ellipse. The ellipse's axes give the cone's tilt
``alpha`` and the apex's offsets ``s1`` (along the major axis) and ``s2`` (the
height above the plane); the two mirror-image apexes are rotated and moved back.

spotnav's precise method fits the cones themselves instead (:mod:`spotnav.pose.conefit`);
it starts from these candidates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from spotnav.setup.geometry import normalize, rotation_about_y, rotation_about_z

__all__ = [
    "ConeCandidates",
    "Ellipse",
    "apex_candidates",
    "choose_by_insertion",
    "fit_ellipse",
    "sphere_normal",
    "triangle_from_ellipse",
]


@dataclass(frozen=True)
class Ellipse:
    """An ellipse in a plane.

    Attributes
    ----------
    center : ndarray, shape (2,)
    semi_major, semi_minor : float
        Semi-axes, ``semi_major >= semi_minor`` (thesis-notes 2).
    major_direction : ndarray, shape (2,)
        Unit vector along the major axis.
    """

    center: np.ndarray
    semi_major: float
    semi_minor: float
    major_direction: np.ndarray


def fit_ellipse(points: np.ndarray) -> Ellipse:
    """Least-squares ellipse through 2D points, in double precision.

    The direct least-squares fit (Fitzgibbon et al. 1999, in the numerically
    stable form of Halir and Flusser 1998) on points centred and scaled to
    unit spread, as OpenCV's ``fitEllipseDirect`` does in single precision
    (whose axis ratio, and so the tilt, loses the square root of its
    precision near a circle).

    Parameters
    ----------
    points : ndarray, shape (N, 2), N >= 5
        In any unit; the result is in the same unit.

    Raises
    ------
    ValueError
        For fewer than 5 points, points that are not finite, or points no ellipse fits (collinear ones).
    """
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 2 or len(points) < 5:
        raise ValueError(f"need at least 5 points of shape (N, 2), got {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError("the points must be finite")
    fitted, centre, semi_major, semi_minor, major_direction = _fit_ellipse(np.ascontiguousarray(points))
    if not fitted:
        raise ValueError("no ellipse fits these points")
    return Ellipse(centre, semi_major, semi_minor, major_direction)


# Points on a line: the linear terms' scatter matrix's determinant under this many N^3 (on points scaled to unit
# spread it is N^3 / 4 on a circle, r^2 N^3 / 4 on an ellipse of axes r : 1).
_SINGULAR = 1e-12


@njit(cache=True)
def _fit_ellipse(points: np.ndarray) -> tuple[bool, np.ndarray, float, float, np.ndarray]:
    """:func:`fit_ellipse` of points (N, 2), compiled: whether an ellipse fits, its centre, semi-axes and major
    direction."""
    failed = (False, np.zeros(2), np.nan, np.nan, np.zeros(2))
    count = len(points)
    offset = np.array([np.mean(points[:, 0]), np.mean(points[:, 1])])
    spread = 0.0
    for n in range(count):
        spread += (points[n, 0] - offset[0]) ** 2 + (points[n, 1] - offset[1]) ** 2
    scale = np.sqrt(spread / count)
    scale = scale if scale > 0.0 else 1.0
    # The scatter matrices of the quadratic (x^2, xy, y^2) and linear (x, y, 1) terms.
    s1, s2, s3 = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3))
    for n in range(count):
        x, y = (points[n, 0] - offset[0]) / scale, (points[n, 1] - offset[1]) / scale
        quadratic, linear = (x * x, x * y, y * y), (x, y, 1.0)
        for i in range(3):
            for j in range(3):
                s1[i, j] += quadratic[i] * quadratic[j]
                s2[i, j] += quadratic[i] * linear[j]
                s3[i, j] += linear[i] * linear[j]
    # Collinear points (or one point) make s3 singular: refused before solving (an exception raised in compiled
    # code leaks what it had allocated).
    if not np.linalg.det(s3) > _SINGULAR * count**3:
        return failed
    t = -np.linalg.solve(s3, np.ascontiguousarray(s2.T))
    m = s1 + s2 @ t
    m = np.vstack((m[2:3] / 2.0, -m[1:2], m[0:1] / 2.0))  # the inverse of the constraint matrix, applied
    # On exact points rounding may pair the ellipse's eigenvalue (near 0) with another as complex conjugates: the
    # complex decomposition, and the vectors' real parts (the ellipse's imaginary part is rounding).
    _, complex_vectors = np.linalg.eig(m.astype(np.complex128))
    vectors = np.ascontiguousarray(complex_vectors.real)
    chosen = -1
    for k in range(3):
        if chosen < 0 and 4.0 * vectors[0, k] * vectors[2, k] - vectors[1, k] ** 2 > 0:
            chosen = k
    if chosen < 0:
        return failed
    top = np.ascontiguousarray(vectors[:, chosen])
    a, b, c = top[0], top[1], top[2]
    rest = np.ascontiguousarray(t) @ top
    d, e, f = rest[0], rest[1], rest[2]
    # The centre solves the conic's gradient; the axes are its quadratic form's at that centre.
    quadratic_form = np.array([[a, b / 2.0], [b / 2.0, c]])
    centre = np.linalg.solve(quadratic_form, np.array([-d / 2.0, -e / 2.0]))
    level = -(f + 0.5 * (d * centre[0] + e * centre[1]))
    if not (np.isfinite(level) and level != 0.0):
        return failed
    eigenvalues, axes = np.linalg.eigh(quadratic_form / level)
    if not (eigenvalues[0] > 0 and eigenvalues[1] > 0):
        return failed
    semi = 1.0 / np.sqrt(eigenvalues)  # eigh sorts ascending: the major axis first
    return True, offset + scale * centre, scale * semi[0], scale * semi[1], np.ascontiguousarray(axes[:, 0])


@njit(cache=True)
def triangle_from_ellipse(semi_major: float, semi_minor: float, half_angle: float) -> tuple[float, float, float]:
    """The thesis's triangle: cone tilt and apex offsets from an ellipse.

    Parameters
    ----------
    semi_major, semi_minor : float
        The ellipse's semi-axes ``a >= b``.
    half_angle : float
        Cone half-angle beta, radians.

    Returns
    -------
    alpha : float
        Angle between the cone's axis and the plane's normal, radians.
    s1 : float
        Offset of the apex's foot from the ellipse's centre along the major axis.
    s2 : float
        Height of the apex above the plane (same unit as the axes).
    """
    eccentricity = np.sqrt(max(0.0, 1.0 - (semi_minor / semi_major) ** 2))
    alpha = float(np.arcsin(min(1.0, eccentricity * np.cos(half_angle))))  # Eq. 4.29 (thesis-notes 1)
    s1 = semi_major * np.sin(2 * alpha) / np.sin(2 * half_angle)  # Eq. 4.30
    s2 = semi_major * (np.cos(2 * alpha) / np.sin(2 * half_angle) + 1.0 / np.tan(2 * half_angle))  # Eq. 4.31
    return alpha, float(s1), float(s2)


@dataclass(frozen=True)
class ConeCandidates:
    """The two mirror-image cones that fit one contour.

    Attributes
    ----------
    apexes : ndarray, shape (2, 3)
        Candidate apexes in the eye frame, mm.
    cone_axes : ndarray, shape (2, 3)
        Each candidate's beam axis, unit vectors pointing away from the apex.
    ellipse : Ellipse
        The fit in the contour's tangent plane, mm, centred near the plane's origin.
    alpha, s1, s2 : float
        The triangle of :func:`triangle_from_ellipse` (radians, mm, mm), before
        any height correction.
    plane_origin_in_eye, plane_normal_in_eye : ndarray, shape (3,)
        The fitting plane: through the contour's centroid, with the surface's
        unit normal there, pointing toward the apexes.
    status : str
        ``"ok"``, or why the contour gives no cone (one of :data:`spotnav.pose.estimate.STATUSES`); every value
        above is NaN then.
    detail : str
        What was wrong, for a refused contour.
    """

    apexes: np.ndarray
    cone_axes: np.ndarray
    ellipse: Ellipse
    alpha: float
    s1: float
    s2: float
    plane_origin_in_eye: np.ndarray
    plane_normal_in_eye: np.ndarray
    status: str = "ok"
    detail: str = ""

    @property
    def ok(self) -> bool:
        """Whether the contour gave its two cones."""
        return self.status == "ok"

    @classmethod
    def refused(cls, status: str, detail: str) -> ConeCandidates:
        """The candidates of a contour that gives none: NaN everywhere, and why."""
        nan2, nan3 = np.full(2, np.nan), np.full(3, np.nan)
        ellipse = Ellipse(nan2, float("nan"), float("nan"), nan2)
        nan = float("nan")
        return cls(np.full((2, 3), np.nan), np.full((2, 3), np.nan), ellipse, nan, nan, nan, nan3, nan3, status, detail)


def sphere_normal(points_in_eye: np.ndarray, sphere_center: np.ndarray) -> np.ndarray:
    """Inward unit normal of a sphere at the centroid of points on it, shape (3,)."""
    return normalize(np.asarray(sphere_center, float) - np.asarray(points_in_eye, float).mean(axis=0))


def apex_candidates(
    points_in_eye: np.ndarray, surface_normal: np.ndarray, half_angle: float, height_correction: float = 1.0
) -> ConeCandidates:
    """Both apex candidates of a contour on the surface (Algorithm 1), or refused where no ellipse fits it.

    Parameters
    ----------
    points_in_eye : ndarray, shape (N, 3)
        The contour back-projected onto the surface, mm.
    surface_normal : ndarray, shape (3,)
        The surface's unit normal at the contour's centroid, toward the light
        (:func:`sphere_normal` on the retina, ``+z`` on the plane ``z = 0``). It
        must lie in the vertical plane through the centroid, as both do.
    half_angle : float
        Cone half-angle beta, radians.
    height_correction : float
        Section 5.5's factor: scales the triangle (``s1`` and ``s2``) about the
        ellipse's centre, as a uniform growth of the spot would.

    Returns
    -------
    ConeCandidates
        ``unreliable`` for fewer than 5 points, points that are not finite, or
        points no ellipse fits (collinear ones).

    Raises
    ------
    ValueError
        If the points are not of shape (N, 3).
    """
    points_in_eye = np.ascontiguousarray(points_in_eye, dtype=float)
    if points_in_eye.ndim != 2 or points_in_eye.shape[1] != 3:
        raise ValueError(f"points_in_eye must have shape (N, 3), got {points_in_eye.shape}")
    if len(points_in_eye) < 5 or not np.isfinite(points_in_eye).all():
        return ConeCandidates.refused("unreliable", "fewer than 5 finite contour points")
    normal = normalize(np.asarray(surface_normal, dtype=float))
    fitted, apexes, cone_axes, ellipse, triangle, planes = _apex_candidates(
        points_in_eye, normal, float(half_angle), float(height_correction)
    )
    if not fitted:
        return ConeCandidates.refused("unreliable", "no ellipse fits the contour")
    centre, semi_major, semi_minor, major_direction = ellipse
    return ConeCandidates(
        apexes, cone_axes, Ellipse(centre, semi_major, semi_minor, major_direction), *triangle, planes[0], planes[1]
    )


@njit(cache=True)
def _apex_candidates(
    points_in_eye: np.ndarray, normal: np.ndarray, half_angle: float, height_correction: float
) -> tuple[
    bool,
    np.ndarray,
    np.ndarray,
    tuple[np.ndarray, float, float, np.ndarray],
    tuple[float, float, float],
    tuple[np.ndarray, np.ndarray],
]:
    """:func:`apex_candidates` of points (N, 3) and a unit ``normal`` (3,), compiled: whether an ellipse fits, the
    apexes (2, 3), the cone axes (2, 3), the ellipse (centre, semi-axes, major direction), the triangle (alpha, s1,
    s2) and the plane (origin, normal)."""
    centroid = np.array([np.mean(points_in_eye[:, 0]), np.mean(points_in_eye[:, 1]), np.mean(points_in_eye[:, 2])])
    to_x_axis = rotation_about_z(-np.arctan2(centroid[1], centroid[0]))
    normal_on_x = to_x_axis @ normal
    # Rotate about z so the centre lies on +x, then about y so the normal is +z.
    to_plane = rotation_about_y(np.arctan2(-normal_on_x[0], normal_on_x[2])) @ to_x_axis
    in_plane = (points_in_eye - centroid) @ to_plane.T
    fitted, centre, semi_major, semi_minor, major_direction = _fit_ellipse(np.ascontiguousarray(in_plane[:, :2]))
    up = np.array([0.0, 0.0, 1.0])
    ellipse = (centre, semi_major, semi_minor, major_direction)
    if not fitted:
        return False, np.zeros((2, 3)), np.zeros((2, 3)), ellipse, (np.nan, np.nan, np.nan), (centroid, up)
    alpha, s1, s2 = triangle_from_ellipse(semi_major, semi_minor, half_angle)
    major = np.array([major_direction[0], major_direction[1], 0.0])
    apexes, cone_axes = np.empty((2, 3)), np.empty((2, 3))
    for k, sign in enumerate((1.0, -1.0)):
        apex_in_plane = np.array([centre[0], centre[1], 0.0]) + height_correction * (sign * s1 * major + s2 * up)
        # The axis leans from the apex's foot toward the ellipse's centre.
        axis = (-sign * np.sin(alpha) * major - np.cos(alpha) * up) @ to_plane
        apexes[k] = apex_in_plane @ to_plane + centroid
        cone_axes[k] = axis / np.sqrt(np.sum(axis * axis))
    return True, apexes, cone_axes, ellipse, (alpha, s1, s2), (centroid, to_plane.T @ up)


def choose_by_insertion(candidates: ConeCandidates, insertion_in_eye: np.ndarray) -> tuple[int, float]:
    """Pick the candidate whose cone axis runs along the line from the insertion point.

    For one beam the beam axis is the instrument axis, so the true apex ``V``
    has its cone axis along ``V - insertion`` (thesis-notes 6).

    Returns
    -------
    index : int
        0 or 1.
    misalignment : float
        Angle between that candidate's cone axis and its insertion line, radians.
    """
    lines = normalize(candidates.apexes - np.asarray(insertion_in_eye, dtype=float))
    cosines = (lines * candidates.cone_axes).sum(axis=1).clip(-1.0, 1.0)
    index = int(cosines.argmax())
    return index, float(np.arccos(cosines[index]))
