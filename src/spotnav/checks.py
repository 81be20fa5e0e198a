"""The checks that keep the precise methods honest, with their thresholds.

A frame is refused (a :class:`~spotnav.estimate.PoseEstimate` that is not
``ok``) when it is the wrong size, when a spot's edge cannot be trusted
(:func:`edge_problem`), or when the fit fails a consistency check or the
setup's geometry cannot back it (:func:`judge_fit`).
"""

from __future__ import annotations

import numpy as np

from spotnav.camera import camera_depth_mm
from spotnav.conefit import DEFAULT_BLEND, ConeSolution, group_of
from spotnav.config import Camera, Setup
from spotnav.detect import SpotEdge
from spotnav.estimate import PoseEstimate
from spotnav.geometry import edge_angle_of_blend

__all__ = ["MAX_SIGMA_MM", "MIN_EDGE_POINTS", "check_image_size", "edge_problem", "judge_fit", "residuals_px"]

MIN_EDGE_POINTS = 20
_MIN_INLIER_FRACTION = 0.5
# A fit is poor when its edge points lie both this far in angle (some 0.015 deg on a textured retina at 1 W)
# and this far in pixels (some 0.3 px from noise; at most 0.75 px on the frames the fault study accepts at
# 1024 px, 1.4 px for a pose off the insertion line forced through it) from their cones.
MAX_RMS_DEG = 0.1
MAX_RMS_PX = 1.0
_MIN_CONTRAST_TO_NOISE = 20.0  # measured: 60-500 on good frames, 5-10 where heavy noise biased the edge by 0.1 mm
_EDGE_WIDTH_SLACK_PX = 4.0  # measured: widths at most 0.86 of band + 4 px unblurred, 1.1-2 with a 1.5 % motion blur
_MAX_CLIPPED_FRACTION = 0.5  # measured: 0.9-1.0 at +4 stops (edge 0.08-0.1 mm off), mostly under 0.1 at +2 stops
MAX_SIGMA_MM = 0.03  # a pose more uncertain than this is refused: 3 sigma stays within a silent failure's 0.1 mm


def check_image_size(image: np.ndarray, setup: Setup) -> PoseEstimate | None:
    """``wrong_size`` when the image is not the camera's size, else None."""
    expected = (setup.camera.height_px, setup.camera.width_px)
    if image.shape[:2] != expected:
        return PoseEstimate(
            "wrong_size",
            detail=f"image is {image.shape[1]}x{image.shape[0]} px, "
            f"the setup's camera is {expected[1]}x{expected[0]} px",
        )
    return None


def edge_problem(edge: SpotEdge, setup: Setup, radius_px: float, edge_angle: float) -> str | None:
    """Why a spot's edge cannot be trusted, or None.

    Too few points; noise that biases the halfway level (contrast under
    ``_MIN_CONTRAST_TO_NOISE`` times the noise); a plateau clipped at full
    scale in every channel (over ``_MAX_CLIPPED_FRACTION`` of it), which lowers
    that level and moves the edge outward; or an edge wider than the beam's
    soft band (``2 (beta - edge_angle)`` of the spot's radius ``radius_px``,
    at least the default edge model's) plus ``_EDGE_WIDTH_SLACK_PX``: motion
    blur or defocus, which the edge model does not know.
    """
    if len(edge.pixels) < MIN_EDGE_POINTS:
        return "too few edge points"
    if not edge.contrast_to_noise >= _MIN_CONTRAST_TO_NOISE:
        return (
            f"the edge's contrast is {edge.contrast_to_noise:.0f} times the noise, under {_MIN_CONTRAST_TO_NOISE:.0f}"
        )
    if edge.clipped_fraction > _MAX_CLIPPED_FRACTION:
        return f"{100 * edge.clipped_fraction:.0f} % of the spot inside its edge is at full scale in every channel"
    beta = setup.instrument.beam_half_angle
    # The soft band is 2 (beta - edge) wide, at least the default model's: a calibrated edge may lie beyond beta.
    soft = max(beta - edge_angle, beta - edge_angle_of_blend(beta, DEFAULT_BLEND))
    band_px = 2.0 * soft / beta * radius_px
    if edge.width_px > band_px + _EDGE_WIDTH_SLACK_PX:
        return f"the edge is {edge.width_px:.1f} px wide, the beam's {band_px:.1f} px: blurred"
    return None


def residuals_px(
    camera: Camera, points_in_eye: np.ndarray, tips_in_eye: np.ndarray, residuals: np.ndarray
) -> np.ndarray:
    """Angular residuals (N,) as pixels: each point's distance from its tip over its depth, times the focal length.

    Parameters
    ----------
    camera : Camera
    points_in_eye : ndarray, shape (N, 3)
        The edge points on the retina, mm.
    tips_in_eye : ndarray, shape (N, 3) or (3,)
        The tip of each point's frame, mm.
    residuals : ndarray, shape (N,)
        Radians.
    """
    distance = np.linalg.norm(points_in_eye - tips_in_eye, axis=-1)
    return residuals * distance * camera.focal_px / camera_depth_mm(camera, points_in_eye)


def judge_fit(
    solution: ConeSolution,
    setup: Setup,
    *,
    spots: int,
    detail: str = "",
    other_axis: np.ndarray | None = None,
) -> PoseEstimate:
    """A one-frame cone fit as an estimate, or the reason it is refused.

    ``uncalibrated`` when the setup's geometry uncertainty takes the tip's
    uncertainty over :data:`MAX_SIGMA_MM` (a geometry that uncertain may also
    cause any other problem, which the detail adds); else ``unreliable`` when
    the fit fails a consistency check (too few inliers, a residual too large
    in both degrees and pixels, its own tip uncertainty over that limit, a tip
    outside the eye). The estimate's ``sigma_mm`` carries the geometry's
    uncertainty.

    Parameters
    ----------
    solution : ConeSolution
        A one-frame fit.
    setup : Setup
    spots : int
        Spots used, for the estimate.
    detail : str
        A remark to carry on an ``ok`` estimate.
    other_axis : ndarray, shape (3,), optional
        The cross-check axis.
    """
    tip = solution.tip()
    residual_px = residuals_px(setup.camera, solution.problem.points_in_eye, tip, solution.residuals)
    inliers = solution.inliers
    rms_px = float(np.sqrt(np.mean(residual_px[inliers] ** 2)))
    rms_deg = float(np.degrees(np.sqrt(np.mean(solution.residuals[inliers] ** 2))))
    own_sigma, sigma = solution.tip_sigma_mm(geometry=False), solution.tip_sigma_mm()
    problems = []
    if inliers.mean() < _MIN_INLIER_FRACTION:
        problems.append(f"only {100 * inliers.mean():.0f} % of the edge fits the cones")
    if rms_deg > MAX_RMS_DEG and rms_px > MAX_RMS_PX:
        problems.append(f"RMS residual {rms_deg:.3f} deg ({rms_px:.2f} px)")
    if own_sigma > MAX_SIGMA_MM:
        problems.append(f"tip uncertainty {own_sigma:.3f} mm")
    if not setup.contains_point(tip):
        problems.append("the fitted tip lies outside the eye")
    if not solution.settled:
        problems.append("the fitted tip is held at the edge of its 2 mm box")
    common = {"spots": spots, "sigma_mm": sigma, "rms_px": rms_px}
    if sigma > MAX_SIGMA_MM >= own_sigma:  # a geometry this uncertain may also explain any other problem
        return PoseEstimate("uncalibrated", detail="; ".join([_geometry_blame(solution, sigma), *problems]), **common)
    if problems:
        return PoseEstimate("unreliable", detail="; ".join(problems), **common)
    return PoseEstimate(
        "ok", tip_in_eye=tip, axis=solution.axis(), roll=solution.roll(), other_axis=other_axis, detail=detail, **common
    )


def _geometry_blame(solution: ConeSolution, sigma: float) -> str:
    """Which parts of the geometry make the tip so uncertain."""
    shares: dict[str, float] = {}
    for index, share in zip(solution.geometry_ids, solution.geometry_share(), strict=True):
        shares[group_of(index)] = shares.get(group_of(index), 0.0) + share
    total = max(sum(shares.values()), 1e-30)
    named = [f"{name} {100 * share / total:.0f} %" for name, share in sorted(shares.items(), key=lambda i: -i[1])]
    return (
        f"the setup's geometry leaves the tip uncertain by {sigma:.3f} mm (1 sigma; {', '.join(named[:3])}): "
        "calibrate it (spotnav calibrate) or state a smaller [uncertainty]"
    )
