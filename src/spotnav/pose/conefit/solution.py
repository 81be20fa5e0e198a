"""A fitted cone problem: :class:`ConeSolution`, each frame's tip, axis and roll and how well the fit knows them.

A solution holds the fitted parameters, the points' residuals and which points the fit kept; its uncertainty
(:mod:`spotnav.pose.conefit.covariance`) is computed on first use. One frame of a joint fit is a solution of its own
(:meth:`ConeSolution.frame_solution`), and a fit whose residuals the points' noise does not explain widens its
uncertainty by a shift of the edges (:meth:`ConeSolution.with_edge_shift`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import cached_property, partial

import numpy as np
from numba import njit

from spotnav.pose.conefit.covariance import FitUncertainty, _block_uncertainty, _uncertainty
from spotnav.pose.conefit.model import _instrument_axis
from spotnav.pose.conefit.parameters import _EDGE, _INSERTION, _TILT
from spotnav.pose.conefit.problem import ConeProblem, EdgePoints

__all__ = ["ConeSolution"]


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
        Returns the fit's :class:`~spotnav.pose.conefit.covariance.FitUncertainty`, computed on first use (a
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
        """The fit's uncertainty (see :class:`~spotnav.pose.conefit.covariance.FitUncertainty`), computed once."""
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
        """How the fixed geometry moves the free parameters (P, G), see
        :class:`~spotnav.pose.conefit.covariance.FitUncertainty`."""
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
        point: np.ndarray = self.problem.base[3:6] + self.shared[_INSERTION:_TILT]
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
        """Covariance of ``frame``'s parameters ``which`` (indices of
        :data:`~spotnav.pose.conefit.parameters.FRAME_PARAMETERS`), with or without the fixed geometry's part; zero
        for parameters that were not fitted."""
        index = self.problem.arrays.frame_index[frame, list(which)]
        covariance = self.covariance if geometry else self.data_covariance
        fitted = index >= 0
        if fitted.all():
            block: np.ndarray = covariance[index[:, None], index]
            return block
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
        return self.problem.arrays.frame_index[frame, :3]

    def frame_solution(self, frame: int) -> ConeSolution:
        """One frame of a joint fit as a one-frame solution: its points, its block of the covariance.

        The points are seen in the fitted geometry; the block carries the
        shared parameters' uncertainty through its correlations.
        """
        problem = self.problem
        rows = problem.points.frame == frame
        points = problem.points.subset(rows)
        spots, spot = np.unique(points.spot, return_inverse=True)
        if points.spot_sigma is None:  # impossible: EdgePoints.__post_init__ sets it
            raise RuntimeError("edge points without their spots' sigmas")
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
        index = problem.arrays.frame_index[frame]
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
        (:func:`~spotnav.pose.conefit.covariance.scatter_covariance`'s ``contour_sigma``) and, since a light
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
        if points.spot_sigma is None:  # impossible: EdgePoints.__post_init__ sets it
            raise RuntimeError("edge points without their spots' sigmas")
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
        share: np.ndarray = np.sum(gain * (gain @ prior), axis=0)
        return share


@njit(cache=True)
def _free_trace(covariance: np.ndarray, index: np.ndarray) -> float:
    """The sum of ``covariance``'s (P, P) diagonal at the free ones of ``index`` (K,) (those not -1), in order."""
    total = 0.0
    for i in index:
        if i >= 0:
            total += covariance[i, i]
    return total


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
