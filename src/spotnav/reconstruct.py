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
from scipy.optimize import least_squares

from spotnav.geometry import axis_rotations, beam_axes, normalize, rotation_about_y, rotation_about_z

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


def _instrument_axes(params: np.ndarray, insertion_in_eye: np.ndarray | None) -> np.ndarray:
    """Instrument axes of parameter sets ``params`` (K, P), shape (K, 3)."""
    if insertion_in_eye is not None:
        offsets = params[:, :3] - insertion_in_eye
        return offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    about_y, about_z = params[:, 3], params[:, 4]
    # rotation_about_z(about_z) @ rotation_about_y(about_y) @ (0, 0, -1)
    return np.column_stack([-np.sin(about_y) * np.cos(about_z), -np.sin(about_y) * np.sin(about_z), -np.cos(about_y)])


def _cone_residuals(
    params: np.ndarray,
    points: np.ndarray,
    beam_of_point: np.ndarray,
    edge_angle: float,
    beam_count: int,
    tilt: float,
    insertion_in_eye: np.ndarray | None,
    light_radius: float,
) -> np.ndarray:
    """Angle of each point from its beam's cone, for parameter sets ``params`` (K, P): shape (K, N).

    The cone is widened by ``light_radius`` (mm): a point's distance from the
    beam's axis less that radius, against its distance along the axis.
    """
    axes = _instrument_axes(params, insertion_in_eye)
    rolls = params[:, -1] if beam_count > 1 else np.zeros(len(params))
    beams = axes[:, None, :] if beam_count == 1 else beam_axes(axes, beam_count, tilt, rolls)
    rays = points[None, :, :] - params[:, None, :3]
    along = np.einsum("knj,knj->kn", rays, beams[:, beam_of_point])
    across = np.sqrt(np.maximum(np.einsum("knj,knj->kn", rays, rays) - along**2, 0.0))
    return np.arctan2(across - light_radius, along) - edge_angle


def _residuals_and_jacobian(params: np.ndarray, *args: object) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (N,) at ``params`` (P,) and their forward-difference Jacobian (N, P), in one batched call."""
    steps = 1e-7 * np.maximum(np.abs(params), 1.0)
    batch = np.vstack([params, params + np.diag(steps)])
    residuals = _cone_residuals(batch, *args)
    return residuals[0], ((residuals[1:] - residuals[0]) / steps[:, None]).T


def _gauss_newton_step(
    params: np.ndarray, residuals: np.ndarray, jacobian: np.ndarray, scale: float | None
) -> np.ndarray:
    """One Gauss-Newton step from ``params``; with ``scale``, reweighted for the soft-L1 loss."""
    weights = np.ones_like(residuals) if scale is None else 1.0 / np.sqrt(1.0 + (residuals / scale) ** 2)
    weighted = jacobian.T * weights
    return params - np.linalg.solve(weighted @ jacobian, weighted @ residuals)


def _solve_trust_region(
    params: np.ndarray, args: tuple, scale: float | None, tip_box: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """SciPy's trust-region least squares from ``params``, the tip kept in ``tip_box``; with ``scale``, soft-L1.

    Returns the parameters, the residuals and the Jacobian at them.
    """
    unbounded = np.full(len(params) - 3, np.inf)
    result = least_squares(
        lambda x: _cone_residuals(x[None, :], *args)[0],
        params,
        jac=lambda x: _residuals_and_jacobian(x, *args)[1],
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
    points = np.concatenate(points_in_eye)
    beam_of_point = np.concatenate([np.full(len(p), b) for p, b in zip(points_in_eye, beams, strict=True)])
    start = list(np.asarray(tip_in_eye, dtype=float))
    if insertion_in_eye is None:
        start += list(axis_rotations(axis))
    if beam_count > 1:
        start.append(roll)
    args = (points, beam_of_point, edge_angle, beam_count, tilt, insertion_in_eye, light_radius)
    params = np.array(start)
    residuals, jacobian = _residuals_and_jacobian(params, *args)
    scale = max(1.4826 * float(np.median(np.abs(residuals - np.median(residuals)))), 1e-6)
    # The tip may not wander off: a short arc of edge also fits a narrow far cone (with the axis through
    # the insertion point, one whose apex sits at that point); the start is within a millimetre.
    tip_box = (params[:3] - _MAX_TIP_MOVE_MM, params[:3] + _MAX_TIP_MOVE_MM)
    if solver == "trust-region":
        params, residuals, _ = _solve_trust_region(params, args, scale, tip_box)
    else:
        for _ in range(2):
            params = _gauss_newton_step(params, residuals, jacobian, scale)
            residuals, jacobian = _residuals_and_jacobian(params, *args)
    spread = max(1.4826 * float(np.median(np.abs(residuals))), 1e-7)
    inliers = np.abs(residuals) < 3.0 * spread
    if solver == "trust-region":
        kept = (points[inliers], beam_of_point[inliers], *args[2:])
        params, fun, jacobian = _solve_trust_region(params, kept, None, tip_box)
        residuals = _cone_residuals(params[None, :], *args)[0]
    else:
        params = _gauss_newton_step(params, residuals[inliers], jacobian[inliers], None)
        residuals, jacobian = _residuals_and_jacobian(params, *args)
        fun, jacobian = residuals[inliers], jacobian[inliers]
    dof = max(int(inliers.sum()) - len(params), 1)
    variance = float(np.sum(fun**2)) / dof
    normal_inverse = np.linalg.pinv(jacobian.T @ jacobian)
    covariance = variance * correlation_inflation(fun, beam_of_point[inliers]) * normal_inverse
    # A change d of the edge angle shifts every residual by -d: the pose moves by (J^T J)^-1 J^T 1 d.
    # A shift of one contour's edge alone moves it by (J^T J)^-1 J_c^T 1 d.
    kept_groups = beam_of_point[inliers]
    shifts = np.stack([normal_inverse @ jacobian[kept_groups == b].sum(axis=0) for b in np.unique(kept_groups)])
    shift = shifts.sum(axis=0)
    covariance = covariance + edge_sigma**2 * np.outer(shift, shift) + contour_sigma**2 * shifts.T @ shifts
    return ConeFit(
        tip_in_eye=params[:3].copy(),
        axis=_instrument_axes(params[None, :], insertion_in_eye)[0],
        roll=float(params[-1]) if beam_count > 1 else 0.0,
        residuals=residuals,
        inliers=inliers,
        tip_covariance=covariance[:3, :3],
    )


def correlation_inflation(residuals: np.ndarray, groups: np.ndarray) -> float:
    """Variance inflation ``(1 + rho) / (1 - rho)`` for the lag-1 correlation of neighbouring residuals.

    Parameters
    ----------
    residuals : ndarray, shape (N,)
        In order along each contour.
    groups : ndarray, shape (N,)
        Which contour each residual belongs to (neighbours are taken within one).
    """
    group_index = np.unique(groups, return_inverse=True)[1]
    means = np.bincount(group_index, residuals) / np.bincount(group_index)
    r = residuals - means[group_index]
    neighbours = group_index[1:] == group_index[:-1]
    products, squares = float(np.sum((r[1:] * r[:-1])[neighbours])), float(np.sum(r * r))
    rho = float(np.clip(products / squares, 0.0, 0.9)) if squares > 0 else 0.0
    return (1.0 + rho) / (1.0 - rho)
