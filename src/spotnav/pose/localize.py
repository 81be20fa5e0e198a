"""Localize the instrument tip in one camera frame, by a named method.

Methods (:data:`METHODS`): ``thesis`` (the thesis's Algorithms 1 and 2,
:mod:`spotnav.pose.thesis`), ``precise`` (the default: sub-pixel edges and a direct
cone fit with the axis through the insertion point, :mod:`spotnav.pose.precise`)
and ``precise-free`` (the axis fitted too); see ``docs/methods.md``. Every
method returns a :class:`~spotnav.pose.estimate.PoseEstimate`: a pose with status
``ok``, or a status that says why there is none. No method makes up a pose.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np

from spotnav.optics.light import edge_angle
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.precise import localize_precise, localize_precise_with_edges
from spotnav.pose.thesis import localize_thesis, localize_thesis_with_spots
from spotnav.setup.config import Setup
from spotnav.setup.geometry import beam_axes

__all__ = [
    "DEFAULT_METHOD",
    "METHODS",
    "Cone",
    "Localization",
    "SpotDetail",
    "cones_of_estimate",
    "localize",
    "localize_detailed",
]

METHODS: dict[str, Callable[[np.ndarray, Setup], PoseEstimate]] = {
    "precise": localize_precise,
    "precise-free": partial(localize_precise, through_insertion=False),
    "thesis": localize_thesis,
}
DEFAULT_METHOD = "precise"


def localize(image: np.ndarray, setup: Setup, method: str = DEFAULT_METHOD) -> PoseEstimate:
    """Localize the tip with a named method (see :data:`METHODS`).

    Raises
    ------
    ValueError
        For an unknown method.
    """
    _check_method(method)
    return METHODS[method](image, setup)


def _check_method(method: str) -> None:
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")


@dataclass(frozen=True)
class SpotDetail:
    """One spot as the method saw it.

    Attributes
    ----------
    beam : int
        The beam that made it (0 for one beam; the thesis method: the spot's order).
    edge_px : ndarray, shape (N, 2)
        Every edge point found, pixels (the precise method's sub-pixel edge, the thesis's contour).
    fitted_px : ndarray, shape (M, 2)
        The points the cone fit used (the shaft's hidden ones left out); empty for the thesis method.
    inliers : ndarray of bool, shape (M,)
        The fitted points the robust fit kept.
    residuals_deg : ndarray, shape (M,)
        Each fitted point's angle from its fitted cone, degrees.
    """

    beam: int
    edge_px: np.ndarray
    fitted_px: np.ndarray
    inliers: np.ndarray
    residuals_deg: np.ndarray


@dataclass(frozen=True)
class Cone:
    """A fitted light cone in the eye frame: apex (the tip, mm), unit axis, and the half-angle of its edge (deg)."""

    apex_in_eye: np.ndarray
    axis_in_eye: np.ndarray
    half_angle_deg: float


@dataclass(frozen=True)
class Localization:
    """One frame's answer with what it came from, for inspection (:func:`localize_detailed`).

    Attributes
    ----------
    estimate : PoseEstimate
        The same answer as :func:`localize`.
    spots : tuple of SpotDetail
        The spots the method used (empty when it found none to use).
    cones : tuple of Cone
        The fitted cones, one per beam: from the fit when one ran (also for a
        refused fit, to show what was refused), else from the pose; empty without either.
    tip_covariance_mm2 : ndarray, shape (3, 3)
        The tip's covariance, eye frame, mm^2 (the precise methods' fit; NaN otherwise).
    """

    estimate: PoseEstimate
    spots: tuple[SpotDetail, ...]
    cones: tuple[Cone, ...]
    tip_covariance_mm2: np.ndarray


def _cones(setup: Setup, tip: np.ndarray, axis: np.ndarray, roll: float, half_angle: float) -> tuple[Cone, ...]:
    instrument = setup.instrument
    axes = beam_axes(axis, instrument.beam_count, instrument.beam_tilt, roll).reshape(-1, 3)
    return tuple(Cone(tip.copy(), beam, float(np.degrees(half_angle))) for beam in axes)


def cones_of_estimate(setup: Setup, estimate: PoseEstimate) -> tuple[Cone, ...]:
    """The cones of an ``ok`` estimate's pose with the setup's edge model (none without a pose)."""
    if estimate.tip_in_eye is None or estimate.axis is None:
        return ()
    return _cones(setup, estimate.tip_in_eye, estimate.axis, estimate.roll, edge_angle(setup))


def localize_detailed(image: np.ndarray, setup: Setup, method: str = DEFAULT_METHOD) -> Localization:
    """:func:`localize`, with the edge points, the fitted cones, the residuals and the tip's covariance.

    Raises
    ------
    ValueError
        For an unknown method.
    """
    _check_method(method)
    no_covariance = np.full((3, 3), np.nan)
    empty = np.zeros((0, 2))
    if method == "thesis":
        estimate, detection = localize_thesis_with_spots(image, setup)
        spots = tuple(
            SpotDetail(i, spot.contour_px, empty, np.zeros(0, bool), np.zeros(0))
            for i, spot in enumerate(detection.spots if detection is not None else ())
        )
        cones: tuple[Cone, ...] = ()
        if estimate.tip_in_eye is not None and estimate.axis is not None:
            cones = _cones(setup, estimate.tip_in_eye, estimate.axis, 0.0, setup.instrument.beam_half_angle)
        return Localization(estimate, spots, cones, no_covariance)
    result = localize_precise_with_edges(image, setup, through_insertion=method == "precise")
    estimate, edges, fit = result.estimate, result.edges, result.fit
    spots = ()
    if edges is not None:
        points = fit.problem.points if fit is not None else None
        details = []
        for index, (edge, beam) in enumerate(zip(edges.edges_px, edges.beams, strict=True)):
            if points is None or fit is None:
                details.append(SpotDetail(beam, edge, empty, np.zeros(0, bool), np.zeros(0)))
                continue
            rows = points.spot == index
            residuals = np.degrees(fit.residuals[rows])
            details.append(SpotDetail(beam, edge, points.pixels[rows], fit.inliers[rows], residuals))
        spots = tuple(details)
    cones = ()
    covariance = no_covariance
    if fit is not None:
        cones = _cones(setup, fit.tip(), fit.axis(), fit.roll(), edge_angle(setup))
        covariance = fit.tip_covariance()
    else:
        cones = cones_of_estimate(setup, estimate)
    return Localization(estimate, spots, cones, covariance)
