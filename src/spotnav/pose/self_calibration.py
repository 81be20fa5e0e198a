"""Self-calibration of the eye's radius from a sequence: one radius fitted with every frame's pose, no pose known.

Only the true radius puts every frame's back-projected edge on a right circular
cone of the edge angle with its axis through the insertion point, so the
radius is fitted with all poses at once (one cone problem of
:mod:`spotnav.pose.conefit`, the tips, rolls and radius free), starting from
each frame's precise fit at the setup's radius (:func:`prepare_self_calibration`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from spotnav.errors import InputError
from spotnav.pose.checks import judge_fit
from spotnav.pose.conefit.parameters import PARAMETER_GROUPS
from spotnav.pose.conefit.problem import EdgePoints, cone_problem
from spotnav.pose.conefit.solvers import fit_cones
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.known_frame import FIND_RADIUS_PX, RAYS
from spotnav.pose.precise import EdgeFrame, localize_precise_with_edges
from spotnav.setup.config import Setup

__all__ = [
    "MIN_FRAMES_FOR_SELF_CALIBRATION",
    "RadiusSelfCalibration",
    "prepare_self_calibration",
    "self_calibrate_radius",
]

MIN_FRAMES_FOR_SELF_CALIBRATION = 20


@dataclass(frozen=True)
class RadiusSelfCalibration:
    """The eye's radius fitted jointly with the poses of a sequence, and those poses.

    Attributes
    ----------
    radius_mm, radius_sigma_mm : float
    estimates : list of PoseEstimate
        One per frame, in order; frames the fit could not use keep their status.
    frames : int
        Frames in the joint fit.
    """

    radius_mm: float
    radius_sigma_mm: float
    estimates: list[PoseEstimate]
    frames: int


def prepare_self_calibration(image: np.ndarray, setup: Setup) -> tuple[PoseEstimate, EdgeFrame | None]:
    """One frame's share of :func:`self_calibrate_radius`: its precise pose and its edges (None if unusable).

    A frame refused ``mismatch`` (its edges do not fit the setup's geometry,
    which may be the radius the joint fit is about to find) is used too,
    from its fit's pose.
    """
    result = localize_precise_with_edges(image, setup, max_rays=RAYS, find_radius_px=FIND_RADIUS_PX)
    estimate, prepared, fit = result.estimate, result.edges, result.fit
    if estimate.status == "mismatch" and fit is not None and prepared is not None:
        start = PoseEstimate("ok", tip_in_eye=fit.tip(), axis=fit.axis(), roll=fit.roll(), spots=estimate.spots)
        return start, prepared
    return estimate, prepared if estimate.ok else None


def self_calibrate_radius(
    frames_or_images: Sequence[np.ndarray] | Sequence[tuple[PoseEstimate, EdgeFrame | None]], setup: Setup
) -> RadiusSelfCalibration:
    """Fit one eye radius and every frame's pose together, without known poses.

    Only the true radius puts every frame's back-projected edge on a right
    circular cone of the edge angle with its axis through the insertion point,
    so the radius is fitted with all poses at once (one cone problem, the
    tips, rolls and radius free), starting from each frame's precise fit at
    the setup's radius.

    Parameters
    ----------
    frames_or_images : sequence
        The frames, or what :func:`prepare_self_calibration` made of each
        (so that frames can be prepared elsewhere, in parallel).
    setup : Setup

    Raises
    ------
    InputError
        With fewer than 20 usable frames.
    """
    shares = [f if isinstance(f, tuple) else prepare_self_calibration(f, setup) for f in frames_or_images]
    estimates = [estimate for estimate, _ in shares]
    used = [index for index, (_, prepared) in enumerate(shares) if prepared is not None]
    if len(used) < MIN_FRAMES_FOR_SELF_CALIBRATION:
        raise InputError(
            f"fitting the radius from the frames alone needs at least {MIN_FRAMES_FOR_SELF_CALIBRATION} frames "
            f"with a pose, got {len(used)}"
        )
    prepared = [shares[i][1] for i in used]
    starts = [estimates[i] for i in used]
    points = EdgePoints.of_frames(
        [p.edges_px for p in prepared],  # type: ignore[union-attr]
        [p.beams for p in prepared],  # type: ignore[union-attr]
        [p.edge_sigmas for p in prepared],  # type: ignore[union-attr]
    )
    problem = cone_problem(
        setup,
        points,
        np.array([e.tip_in_eye for e in starts]),
        np.array([e.axis for e in starts]),
        np.array([e.roll for e in starts]),
        free_shared=PARAMETER_GROUPS["eye-radius"],
    )
    solution = fit_cones(problem)
    radius = float(setup.eye.radius_mm + solution.shared[PARAMETER_GROUPS["eye-radius"][0]])
    fitted = replace(setup, eye=replace(setup.eye, radius_mm=radius))
    for f, index in enumerate(used):
        judged = judge_fit(solution.frame_solution(f), fitted, spots=len(prepared[f].edges_px))  # type: ignore[union-attr]
        estimates[index] = replace(judged, detail=f"eye radius fitted over {len(used)} frames: {radius:.3f} mm")
    sigma = float(np.sqrt(solution.covariance[0, 0]))
    return RadiusSelfCalibration(radius, sigma, estimates, len(used))
