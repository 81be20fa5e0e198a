"""From a spot's contour to the cone's apex: the thesis's ellipse method and spotnav's cone fit.

The thesis's (4.4, Algorithm 1), :func:`apex_candidates`: the contour is
back-projected onto the retina sphere, moved to the origin, rotated about ``z``
then ``y`` so that the sphere's tangent plane at its centre becomes the ``xy``
plane, and fitted with an ellipse. The ellipse's axes give the cone's tilt
``alpha`` and the apex's offsets ``s1`` (along the major axis) and ``s2`` (the
height above the plane); the two mirror-image apexes are rotated and moved back.

spotnav's (:func:`fit_cones`) fits the cones themselves to the edge points on
the sphere, by robust nonlinear least squares, for one or three beams at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit
from scipy.optimize import least_squares

from spotnav.geometry import _beam_axes, axis_rotations, normalize, rotation_about_y, rotation_about_z

__all__ = [
    "SOLVERS",
    "ConeCandidates",
    "ConeFit",
    "Ellipse",
    "apex_candidates",
    "choose_by_insertion",
    "correlation_inflation",
    "fit_cones",
    "fit_ellipse",
    "least_squares_covariance",
    "robust_sigma",
    "sphere_normal",
    "triangle_from_ellipse",
]

_FIT_SCALE = 1000.0  # fitEllipse works in float32: fit in micrometres


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
    """Least-squares ellipse through 2D points with OpenCV's ``fitEllipse``.

    Parameters
    ----------
    points : ndarray, shape (N, 2), N >= 5
        In any unit; the result is in the same unit.
    """
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 2 or len(points) < 5:
        raise ValueError(f"need at least 5 points of shape (N, 2), got {points.shape}")
    (cx, cy), (width, height), angle_deg = cv2.fitEllipse(points.astype(np.float32))
    angle = np.radians(angle_deg)
    width_direction = np.array([np.cos(angle), np.sin(angle)])
    height_direction = np.array([-np.sin(angle), np.cos(angle)])
    if width >= height:
        major, minor, direction = width, height, width_direction
    else:
        major, minor, direction = height, width, height_direction
    return Ellipse(np.array([cx, cy]), major / 2.0, minor / 2.0, direction)


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
    """

    apexes: np.ndarray
    cone_axes: np.ndarray
    ellipse: Ellipse
    alpha: float
    s1: float
    s2: float
    plane_origin_in_eye: np.ndarray
    plane_normal_in_eye: np.ndarray


def sphere_normal(points_in_eye: np.ndarray, sphere_center: np.ndarray) -> np.ndarray:
    """Inward unit normal of a sphere at the centroid of points on it, shape (3,)."""
    return normalize(np.asarray(sphere_center, float) - np.asarray(points_in_eye, float).mean(axis=0))


def apex_candidates(
    points_in_eye: np.ndarray, surface_normal: np.ndarray, half_angle: float, height_correction: float = 1.0
) -> ConeCandidates:
    """Both apex candidates of a contour on the surface (Algorithm 1).

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
    """
    points_in_eye = np.asarray(points_in_eye, dtype=float)
    centroid = points_in_eye.mean(axis=0)
    normal = normalize(np.asarray(surface_normal, dtype=float))
    azimuth = np.arctan2(centroid[1], centroid[0])
    to_x_axis = rotation_about_z(-azimuth)
    normal_on_x = to_x_axis @ normal
    slope = np.arctan2(-normal_on_x[0], normal_on_x[2])
    # Rotate about z so the centre lies on +x, then about y so the normal is +z.
    to_plane = rotation_about_y(slope) @ to_x_axis
    in_plane = (points_in_eye - centroid) @ to_plane.T
    fit = fit_ellipse(in_plane[:, :2] * _FIT_SCALE)
    ellipse = Ellipse(
        fit.center / _FIT_SCALE, fit.semi_major / _FIT_SCALE, fit.semi_minor / _FIT_SCALE, fit.major_direction
    )
    alpha, s1, s2 = triangle_from_ellipse(ellipse.semi_major, ellipse.semi_minor, half_angle)
    major = np.array([*ellipse.major_direction, 0.0])
    up = np.array([0.0, 0.0, 1.0])
    signs = np.array([1.0, -1.0])[:, None]
    apexes_in_plane = np.array([*ellipse.center, 0.0]) + height_correction * (signs * s1 * major + s2 * up)
    # The axis leans from the apex's foot toward the ellipse's centre.
    axes_in_plane = -signs * np.sin(alpha) * major - np.cos(alpha) * up
    return ConeCandidates(
        apexes=apexes_in_plane @ to_plane + centroid,
        cone_axes=normalize(axes_in_plane @ to_plane),
        ellipse=ellipse,
        alpha=alpha,
        s1=s1,
        s2=s2,
        plane_origin_in_eye=centroid,
        plane_normal_in_eye=to_plane.T @ up,
    )


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
    cosines = np.clip(np.sum(lines * candidates.cone_axes, axis=1), -1.0, 1.0)
    index = int(np.argmax(cosines))
    return index, float(np.arccos(cosines[index]))


@dataclass(frozen=True)
class ConeFit:
    """The instrument pose whose light cones best explain the edge points (spotnav's precise method).

    Attributes
    ----------
    tip_in_eye : ndarray, shape (3,)
        Fitted tip (the cones' common apex), mm.
    axis : ndarray, shape (3,)
        Instrument axis, unit, insertion point toward the tip.
    roll : float
        Roll about the axis, radians (contract convention; 0 for one beam).
    residuals : ndarray, shape (N,)
        Angle of each edge point from its cone's surface, radians, all points in input order.
    inliers : ndarray of bool, shape (N,)
        Points kept by the robust fit.
    tip_covariance : ndarray, shape (3, 3)
        Covariance of the tip, mm^2, from the Jacobian and the inliers' residuals,
        inflated for the correlation of neighbouring points.
    """

    tip_in_eye: np.ndarray
    axis: np.ndarray
    roll: float
    residuals: np.ndarray
    inliers: np.ndarray
    tip_covariance: np.ndarray

    @property
    def tip_sigma_mm(self) -> float:
        """1-sigma tip uncertainty per axis: the square root of a third of the covariance's trace, mm."""
        return float(np.sqrt(np.trace(self.tip_covariance) / 3))


@njit(cache=True)
def _instrument_axis(params: np.ndarray, insertion_in_eye: np.ndarray) -> np.ndarray:
    """Instrument axis (3,) of the parameters ``params`` (P,).

    Toward the tip ``params[:3]`` from the insertion point, or, where ``insertion_in_eye`` is NaN, the
    rotations ``params[3:5]`` (see :func:`spotnav.geometry.axis_rotations`).
    """
    if not np.isnan(insertion_in_eye[0]):
        offset = params[:3] - insertion_in_eye
        return offset / np.sqrt(np.sum(offset * offset))
    about_y, about_z = params[3], params[4]
    # rotation_about_z(about_z) @ rotation_about_y(about_y) @ (0, 0, -1)
    return np.array([-np.sin(about_y) * np.cos(about_z), -np.sin(about_y) * np.sin(about_z), -np.cos(about_y)])


@njit(cache=True)
def _cone_residuals(params: np.ndarray, model: tuple) -> np.ndarray:
    """Angle of each point from its beam's cone, for the pose ``params`` (P,): shape (N,).

    ``model`` is ``(points (N, 3), beam_of_point (N,), edge_angle, beam_count, tilt, insertion_in_eye (3,)
    or NaN, light_radius)``. The cone is widened by ``light_radius`` (mm): a point's distance from the
    beam's axis less that radius, against its distance along the axis. Compiled: a pose's few hundred
    points cost microseconds.
    """
    points, beam_of_point, edge_angle, beam_count, tilt, insertion_in_eye, light_radius = model
    beams = _beam_axes(_instrument_axis(params, insertion_in_eye), beam_count, tilt, params[-1])
    angles = np.empty(len(points))
    for n in range(len(points)):
        b = beam_of_point[n]
        x, y, z = points[n, 0] - params[0], points[n, 1] - params[1], points[n, 2] - params[2]
        along = x * beams[b, 0] + y * beams[b, 1] + z * beams[b, 2]
        across = np.sqrt(max(x * x + y * y + z * z - along * along, 0.0))
        angles[n] = np.arctan2(across - light_radius, along) - edge_angle
    return angles


@njit(cache=True)
def _residuals_and_jacobian(params: np.ndarray, model: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (N,) of :func:`_cone_residuals` at ``params`` (P,) and their forward-difference Jacobian (N, P)."""
    residuals = _cone_residuals(params, model)
    jacobian = np.empty((len(residuals), len(params)))
    for p in range(len(params)):
        step = 1e-7 * max(abs(params[p]), 1.0)
        shifted = params.copy()
        shifted[p] += step
        moved = _cone_residuals(shifted, model)
        for n in range(len(residuals)):
            jacobian[n, p] = (moved[n] - residuals[n]) / step
    return residuals, jacobian


def _gauss_newton_step(params: np.ndarray, residuals: np.ndarray, jacobian: np.ndarray, scale: float) -> np.ndarray:
    """One Gauss-Newton step from ``params``; with ``scale`` > 0, reweighted for the soft-L1 loss."""
    normal, gradient = _normal_equations(jacobian, residuals, scale)
    return params - np.linalg.solve(normal, gradient)


@njit(cache=True)
def _normal_equations(jacobian: np.ndarray, residuals: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """``J^T W J`` (P, P) and ``J^T W r`` (P,) for a Jacobian (N, P) and residuals (N,).

    The weights ``W`` are 1, or with ``scale`` > 0 those of the soft-L1 loss (iteratively reweighted least squares).
    """
    count, size = jacobian.shape
    normal, gradient = np.zeros((size, size)), np.zeros(size)
    for n in range(count):
        weight = 1.0 if scale <= 0.0 else 1.0 / np.sqrt(1.0 + (residuals[n] / scale) ** 2)
        for i in range(size):
            gradient[i] += weight * jacobian[n, i] * residuals[n]
            for j in range(size):
                normal[i, j] += weight * jacobian[n, i] * jacobian[n, j]
    return normal, gradient


@njit(cache=True)
def robust_sigma(values: np.ndarray, centred: bool) -> float:
    """1.4826 times the median absolute value of ``values`` (N,), less their median if ``centred``.

    The standard deviation of normally distributed values, robust to outliers.
    """
    centre = np.median(values) if centred else 0.0
    return 1.4826 * np.median(np.abs(values - centre))


def _solve_trust_region(
    params: np.ndarray, args: tuple, scale: float | None, tip_box: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """SciPy's trust-region least squares from ``params``, the tip kept in ``tip_box``; with ``scale``, soft-L1.

    Returns the parameters, the residuals and the Jacobian at them.
    """
    unbounded = np.full(len(params) - 3, np.inf)
    result = least_squares(
        lambda x: _cone_residuals(x, args),
        params,
        jac=lambda x: _residuals_and_jacobian(x, args)[1],
        bounds=(np.concatenate([tip_box[0], -unbounded]), np.concatenate([tip_box[1], unbounded])),
        loss="linear" if scale is None else "soft_l1",
        f_scale=1.0 if scale is None else scale,
        x_scale="jac",
    )
    return result.x, result.fun, result.jac


SOLVERS = ("trust-region", "gauss-newton")
_MAX_TIP_MOVE_MM = 2.0


def fit_cones(
    points_in_eye: list[np.ndarray],
    beams: list[int],
    edge_angle: float,
    *,
    beam_count: int,
    tilt: float,
    tip_in_eye: np.ndarray,
    axis: np.ndarray,
    roll: float = 0.0,
    insertion_in_eye: np.ndarray | None = None,
    edge_sigma: float = 0.0,
    contour_sigma: float = 0.0,
    light_radius: float = 0.0,
    solver: str = "trust-region",
) -> ConeFit:
    """Fit one instrument pose to edge points on the retina, by robust nonlinear least squares.

    Each point's residual is its angle from the surface of its beam's cone (the
    cone of half-angle ``edge_angle`` about the beam axis, apex at the tip): no
    planar ellipse approximation. With ``insertion_in_eye`` the axis runs from it
    to the tip and the unknowns are the tip (and the roll, for three beams);
    without it the axis is free too. A first fit with a soft-L1 loss finds the
    outliers (points more than 3 robust sigmas off); a plain least-squares fit
    of the rest gives the pose and its covariance.

    Parameters
    ----------
    points_in_eye : list of ndarray, shape (N_k, 3)
        Each spot's edge points on the retina, in order around the spot.
    beams : list of int
        The beam (0, 1 or 2) that made each spot.
    edge_angle : float
        Angle of the detected edge from each beam's axis, radians.
    beam_count : int
    tilt : float
        Beam tilt from the instrument axis (three beams), radians.
    tip_in_eye, axis, roll
        The starting pose (the thesis's closed form).
    insertion_in_eye : ndarray, shape (3,), optional
        Constrain the axis through this point.
    edge_sigma : float
        Uncertainty of ``edge_angle`` itself, radians: a bias shared by every
        point, which no number of points averages away. Its effect on the pose
        is added to the covariance.
    contour_sigma : float
        Uncertainty of each contour's edge as a whole, radians: a shift of one
        spot's whole edge (texture and vessels under it) that its own points
        cannot show, independent between spots. Added to the covariance too.
    light_radius : float
        Radius of the light's emitting face, mm: each cone is widened by it
        (``instrument.light_radius_mm``).
    solver : str
        ``trust-region`` (SciPy's, for any start) or ``gauss-newton`` (a few
        fixed steps, iteratively reweighted: fast, for a start close to the
        answer, as in tracking).
    """
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
    points = np.concatenate(points_in_eye).astype(float)
    beam_of_point = np.concatenate([np.full(len(p), b) for p, b in zip(points_in_eye, beams, strict=True)])
    start = list(np.asarray(tip_in_eye, dtype=float))
    if insertion_in_eye is None:
        start += list(axis_rotations(axis))
    if beam_count > 1:
        start.append(roll)
    insertion = np.full(3, np.nan) if insertion_in_eye is None else np.asarray(insertion_in_eye, dtype=float)
    args = (points, beam_of_point, float(edge_angle), int(beam_count), float(tilt), insertion, float(light_radius))
    params = np.array(start)
    residuals, jacobian = _residuals_and_jacobian(params, args)
    scale = max(robust_sigma(residuals, True), 1e-6)
    # The tip may not wander off: a short arc of edge also fits a narrow far cone (with the axis through
    # the insertion point, one whose apex sits at that point); the start is within a millimetre.
    tip_box = (params[:3] - _MAX_TIP_MOVE_MM, params[:3] + _MAX_TIP_MOVE_MM)
    if solver == "trust-region":
        params, residuals, _ = _solve_trust_region(params, args, scale, tip_box)
    else:
        for _ in range(2):
            params = _gauss_newton_step(params, residuals, jacobian, scale)
            residuals, jacobian = _residuals_and_jacobian(params, args)
    spread = max(robust_sigma(residuals, False), 1e-7)
    inliers = np.abs(residuals) < 3.0 * spread
    if solver == "trust-region":
        kept = (points[inliers], beam_of_point[inliers], *args[2:])
        params, fun, jacobian = _solve_trust_region(params, kept, None, tip_box)
        residuals = _cone_residuals(params, args)
    else:
        params = _gauss_newton_step(params, residuals[inliers], jacobian[inliers], 0.0)
        residuals, jacobian = _residuals_and_jacobian(params, args)
        fun, jacobian = residuals[inliers], jacobian[inliers]
    covariance = _pose_covariance(jacobian, fun, beam_of_point[inliers], edge_sigma, contour_sigma)
    return ConeFit(
        tip_in_eye=params[:3].copy(),
        axis=_instrument_axis(params, insertion),
        roll=float(params[-1]) if beam_count > 1 else 0.0,
        residuals=residuals,
        inliers=inliers,
        tip_covariance=covariance[:3, :3],
    )


@njit(cache=True)
def least_squares_covariance(
    jacobian: np.ndarray, residuals: np.ndarray, groups: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Covariance (P, P) of least-squares parameters, and ``(J^T J)^+``, from the fit's Jacobian (N, P) and residuals.

    The residuals' variance (over ``N - P`` degrees of freedom) times ``(J^T J)^+``, inflated for the
    correlation of neighbouring residuals within each of ``groups`` (N,) (:func:`correlation_inflation`).
    """
    variance = np.sum(residuals**2) / max(len(residuals) - jacobian.shape[1], 1)
    normal_inverse = np.linalg.pinv(_normal_equations(jacobian, residuals, 0.0)[0])
    return variance * correlation_inflation(residuals, groups) * normal_inverse, normal_inverse


@njit(cache=True)
def _pose_covariance(
    jacobian: np.ndarray, residuals: np.ndarray, groups: np.ndarray, edge_sigma: float, contour_sigma: float
) -> np.ndarray:
    """:func:`least_squares_covariance` plus the effect of the edge angle's and each contour's uncertainty.

    A change d of the edge angle shifts every residual by -d: the pose moves by ``(J^T J)^-1 J^T 1 d``.
    A shift of one contour's edge alone moves it by ``(J^T J)^-1 J_c^T 1 d``.
    """
    covariance, normal_inverse = least_squares_covariance(jacobian, residuals, groups)
    size = jacobian.shape[1]
    sums = np.zeros((groups.max() + 1, size))  # J_c^T 1 of each contour
    for n in range(len(residuals)):
        for i in range(size):
            sums[groups[n], i] += jacobian[n, i]
    shifts = np.zeros((len(sums), size))  # (J^T J)^-1 J_c^T 1
    for g in range(len(sums)):
        for i in range(size):
            for j in range(size):
                shifts[g, i] += normal_inverse[i, j] * sums[g, j]
    shift = shifts.sum(axis=0)  # (J^T J)^-1 J^T 1: every contour's edge at once
    for i in range(size):
        for j in range(size):
            together = 0.0
            for g in range(len(shifts)):
                together += shifts[g, i] * shifts[g, j]
            covariance[i, j] += edge_sigma**2 * shift[i] * shift[j] + contour_sigma**2 * together
    return covariance


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
