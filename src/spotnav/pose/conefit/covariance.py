"""How well a cone fit knows its free parameters: the covariance of a least-squares fit of the edge points.

The points' own scatter (their variance inflated for the correlation of neighbours along each spot), each spot's
whole-edge shift, and the uncertainty of the geometry that was held fixed (its prior,
:func:`~spotnav.pose.conefit.parameters.geometry_covariance`, carried through the fit's response to it) make a fit's
:class:`FitUncertainty`; a one-frame fit of its own parameters computes it in one compiled call.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numba import njit
from scipy.sparse import csr_matrix

from spotnav.pose.conefit.model import ConeArrays, _dense_rows, _frame_columns, _shared_columns
from spotnav.pose.conefit.problem import ConeProblem

if TYPE_CHECKING:
    from spotnav.pose.conefit.solution import ConeSolution

__all__ = ["FitUncertainty", "correlation_inflation", "scatter_covariance"]


@njit(cache=True)
def _group_sums(matrix: np.ndarray, groups: np.ndarray, count: int) -> np.ndarray:
    """The rows of ``matrix`` (N, P) summed by ``groups`` (N,) in [0, count): shape (count, P)."""
    sums = np.zeros((count, matrix.shape[1]))
    for n in range(matrix.shape[0]):
        for j in range(matrix.shape[1]):
            sums[groups[n], j] += matrix[n, j]
    return sums


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


@njit(cache=True)
def _scaled_pinv(matrix: np.ndarray) -> np.ndarray:
    """The pseudo-inverse of a symmetric positive semi-definite ``matrix`` (P, P), of its scaled form.

    Columns of very different sizes (a rotation's and k3's differ by 10^10): the matrix scaled to a unit
    diagonal is inverted.
    """
    scale = np.sqrt(np.maximum(np.diag(matrix), 1e-300))
    outer = np.outer(scale, scale)
    inverse: np.ndarray = np.linalg.pinv(matrix / outer) / outer
    return inverse


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
    x = np.array(x, dtype=float)  # writable, as the solvers pass it: their compiled kernels, not a read-only twin
    information = None if priors is None else 1.0 / np.asarray(priors, dtype=float) ** 2
    points = problem.points
    if points.spot_sigma is None:  # impossible: EdgePoints.__post_init__ sets it
        raise RuntimeError("edge points without their spots' sigmas")
    if not problem.free_shared and len(problem.frames) == 1:  # one frame's own parameters: one compiled call
        covariance, data, gain, ids = _frame_uncertainty(
            x,
            problem.arrays,
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
    arrays: ConeArrays,
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
