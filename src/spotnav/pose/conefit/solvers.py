"""The cone fit's solvers and its one robust recipe (:func:`fit_cones`).

The recipe: a robust soft-L1 fit finds the outliers (points over 3 robust sigmas off), a least-squares fit of the
rest gives the parameters, and its covariance (:mod:`spotnav.pose.conefit.covariance`) adds, to the points' own
scatter, the shift of each spot's whole edge and the uncertainty of the geometry that was held fixed. Its solves
are SciPy's trust region (any problem, priors, free geometry), or compiled: Levenberg-Marquardt within the tips' box
and a few Gauss-Newton steps (the frames' own parameters, as in tracking). The recipe is one function
(:func:`_fit_recipe`), compiled for the compiled solvers and run by Python for the trust region.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numba import njit
from numba.extending import overload
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix, vstack

from spotnav.pose.conefit.model import ConeArrays, _frame_columns, _residuals
from spotnav.pose.conefit.parameters import EDGE_CONTOUR_SIGMA
from spotnav.pose.conefit.problem import ConeProblem
from spotnav.pose.conefit.solution import ConeSolution, _solution

__all__ = ["SOLVERS", "fit_cones", "robust_sigma"]

SOLVERS = ("trust-region", "levenberg-marquardt", "gauss-newton")
_GAUSS_NEWTON = SOLVERS.index("gauss-newton")
_LEVENBERG_MARQUARDT = SOLVERS.index("levenberg-marquardt")


@njit(cache=True)
def robust_sigma(values: np.ndarray, centred: bool) -> float:
    """1.4826 times the median absolute value of ``values`` (N,), less their median if ``centred``.

    The standard deviation of normally distributed values, robust to outliers.
    """
    centre = np.median(values) if centred else 0.0
    sigma: float = 1.4826 * np.median(np.abs(values - centre))
    return sigma


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
    penalised = None if priors is None else np.isfinite(priors)  # None exactly where weight is

    def fun(values: np.ndarray) -> np.ndarray:
        residuals: np.ndarray = problem.residuals(values)[rows]
        if weight is None:
            return residuals
        return np.concatenate([residuals, weight[penalised] * values[penalised]])

    def jac(values: np.ndarray) -> np.ndarray | csr_matrix:
        matrix = problem.jacobian_matrix(values, rows)
        if weight is None or penalised is None:  # both or neither
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
    x: np.ndarray, arrays: ConeArrays, rows: np.ndarray, scale: float, per_frame: int, steps: int
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
    arrays: ConeArrays,
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
    box = _tip_box(start, problem.arrays.frame_index, float(max_tip_move_mm))
    per_frame, code, arrays = len(problem.free_frame), SOLVERS.index(solver), problem.arrays
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
    (F, 6) as :func:`~spotnav.pose.conefit.problem._parameter_index` gives it)."""
    low, high = np.full(len(start), -np.inf), np.full(len(start), np.inf)
    tips = [i for i in frame_index[:, :3].ravel() if i >= 0]
    tip_index = np.array(tips, dtype=np.int64) if tips else np.empty(0, np.int64)
    for i in tip_index:
        low[i], high[i] = start[i] - reach, start[i] + reach
    return low, high, tip_index


@njit(cache=True)
def _at_box(x: np.ndarray, box: tuple[np.ndarray, np.ndarray, np.ndarray]) -> bool:
    """Whether a tip of ``x`` is held at its box's wall; ``box`` is (low, high, the tips' indices in ``x``)."""
    low, high, tip_index = box
    for i in tip_index:
        if x[i] - low[i] <= _AT_BOX_MM or high[i] - x[i] <= _AT_BOX_MM:
            return True
    return False


@njit(cache=True)
def _fit_recipe(
    x: np.ndarray,
    arrays: ConeArrays,
    per_frame: int,
    box: tuple[np.ndarray, np.ndarray, np.ndarray],
    solver: int,
    context: tuple[ConeProblem, np.ndarray | None] | None,
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
    arrays: ConeArrays,
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
    if context is None:  # impossible: compiled code runs _compiled_solve_step, Python's recipe passes the context
        raise RuntimeError("a solve step in Python needs its context (problem, priors)")
    (problem, priors), (low, high, _) = context, box
    return _solve(problem, x, rows, None if scale <= 0.0 else scale, (low, high), priors), True


@njit(cache=True)
def _levenberg_marquardt_step(
    x: np.ndarray,
    arrays: ConeArrays,
    rows: np.ndarray,
    scale: float,
    per_frame: int,
    box: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> np.ndarray:
    """The recipe's Levenberg-Marquardt solve: :func:`_levenberg_marquardt` in ``box`` at the step's tolerance.

    Its first, barely damped steps can leap from a poor start to the box's wall: such a solve is done again by
    SciPy's trust region, which grows its steps only as the model earns it, from the same start.
    """
    tolerance = _LM_ROBUST_TOLERANCE if scale > 0.0 else _LM_TOLERANCE
    low, high, _ = box
    return _levenberg_marquardt(x, arrays, rows, scale, low, high, per_frame, tolerance)


@overload(_solve_step)
def _compiled_solve_step(  # Numba passes the arguments' Numba types; annotated as the compiled step's, see below
    solver: int,
    x: np.ndarray,
    arrays: ConeArrays,
    rows: np.ndarray,
    scale: float,
    per_frame: int,
    box: tuple[np.ndarray, np.ndarray, np.ndarray],
    context: tuple[ConeProblem, np.ndarray | None] | None,
) -> Callable[..., tuple[np.ndarray, bool]]:
    """:func:`_solve_step` in compiled code: Gauss-Newton's and Levenberg-Marquardt's, not done when the latter
    ends on the box's wall (SciPy's trust region then runs in Python)."""

    def solve_step(  # Numba asks for the overload's own parameters, annotations included
        solver: int,
        x: np.ndarray,
        arrays: ConeArrays,
        rows: np.ndarray,
        scale: float,
        per_frame: int,
        box: tuple[np.ndarray, np.ndarray, np.ndarray],
        context: tuple[ConeProblem, np.ndarray | None] | None,
    ) -> tuple[np.ndarray, bool]:
        if solver == _GAUSS_NEWTON:
            return _gauss_newton(x, arrays, rows, scale, per_frame, 2 if scale > 0.0 else 1), True
        if solver != _LEVENBERG_MARQUARDT:
            raise ValueError("compiled fits are Gauss-Newton's or Levenberg-Marquardt's")
        fitted = _levenberg_marquardt_step(x, arrays, rows, scale, per_frame, box)
        return fitted, not _at_box(fitted, box)

    return solve_step
