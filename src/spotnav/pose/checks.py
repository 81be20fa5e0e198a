"""The checks that keep the precise methods honest, with their thresholds.

A frame is refused (a :class:`~spotnav.pose.estimate.PoseEstimate` that is not
``ok``) when it is the wrong size, when a spot's edge cannot be trusted
(:func:`judge_edge`, an :class:`EdgeVerdict`), or when the fit fails a consistency check or the
setup's geometry cannot back it (:func:`judge_fit`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import NotRequired, TypedDict

import numpy as np
from numba import njit

from spotnav.image.rays import SpotEdge
from spotnav.optics.camera import camera_depth_mm
from spotnav.optics.edgeblur import frame_blur_for_width, frame_blur_shift, response_curve, seen_edge
from spotnav.optics.light import DEFAULT_BLEND, edge_angle
from spotnav.pose.conefit.parameters import PARAMETER_GROUPS, geometry_covariance, group_of
from spotnav.pose.conefit.problem import cone_problem
from spotnav.pose.conefit.solution import ConeSolution
from spotnav.pose.conefit.solvers import fit_cones
from spotnav.pose.estimate import PoseEstimate
from spotnav.setup.config import Setup
from spotnav.setup.geometry import edge_angle_of_blend
from spotnav.setup.microscope import Camera

__all__ = [
    "FIT_RATIO_EXPLAINED",
    "MAX_FIT_RATIO",
    "MAX_SIGMA_MM",
    "MIN_EDGE_POINTS",
    "EdgeVerdict",
    "blur_shift_px",
    "check_image_size",
    "judge_edge",
    "judge_fit",
    "residuals_px",
]

MIN_EDGE_POINTS = 20
_MIN_EDGE_FRACTION = 0.15  # of the rays: a spot with less of its edge found (vessels, glints) is not trusted
_MIN_INLIER_FRACTION = 0.5
# A fit is poor when its edge points lie both this far in angle (some 0.015 deg on a textured retina at 1 W)
# and this far in pixels (some 0.3 px from noise; at most 0.75 px on the frames the fault study accepts at
# 1024 px, 1.4 px for a pose off the insertion line forced through it) from their cones.
MAX_RMS_DEG = 0.1
MAX_RMS_PX = 1.0
_MIN_CONTRAST_TO_NOISE = 20.0  # measured: 60-500 on good frames, 5-10 where heavy noise biased the edge by 0.1 mm
_WIDTH_TOLERANCE_PX = 0.4  # measured: unblurred edges 2.7-3.2 px wide at 256 px where the model says 2.7
_BAND_SLACK = 0.15  # measured: unblurred edges up to 14 % wider than the band's (rays cross ellipses obliquely)
_EDGE_REACH = 2.0
_MAX_BLUR_MM = 0.03  # a blur that may have moved the tip by more than this (height) is refused
_MAX_CLIPPED_FRACTION = 0.5  # measured: 0.9-1.0 at +4 stops (edge 0.08-0.1 mm off), mostly under 0.1 at +2 stops
MAX_SIGMA_MM = 0.03  # a pose more uncertain than this is refused: 3 sigma stays within a silent failure's 0.1 mm
# The fit's own test: its RMS residual over the one its points' noise explains (``fit_ratio``). Measured at 1024 px
# on 8 helix frames each, exact setups: 1.1-1.3 median, at most 1.8 under each of the fault study's default
# disturbances, one beam or three (2.3 defocus, 3.3 a clipped, blurred spot among vessels and glow; up to 46 on
# frames that motion blur smears); three beams whose light is 0.25 deg wider than the setup's: 5.9-12 (512 px:
# 1.8-5.6); one beam: as matching frames (docs/methods.md, 8).
_HARMONICS = 6  # a misfit bends each edge by its first few harmonics (an ellipse of the wrong size, tilt or shape)
# ... but the fundus bends an edge too, where a vessel or the mottling crosses it: over some 0.25 mm of the edge (a
# vessel 0.1-0.15 mm across, crossing aslant, with the soft band and the reader's window). A harmonic whose half period
# along the edge is shorter is the noise's: a spot 0.3 mm across on the retina (6 deg, 3 mm high) keeps 3, one of
# 0.5 mm or more all 6. Measured (512 px, 6 deg, exact world, retina): fit_ratio 2.8-3.2 with 6, 1.0-1.4 with 3;
# the flat fundus 1.0 either way. Spots of 0.5 mm or more (the fault and mismatch studies' at 512 px) are unchanged.
_BEND_MM = 0.25
_MIN_HARMONICS = 2  # an ellipse of the wrong size, place or shape: what any misfit shows
_MIN_NOISE_POINTS = 40  # a spot's inliers, for its noise: some three per term of the series
FIT_RATIO_EXPLAINED = 1.5  # up to this the noise explains the residuals; beyond it the excess widens sigma
MAX_FIT_RATIO = 4.0  # beyond this no noise does: ``mismatch``


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


def blur_shift_px(edge: SpotEdge, setup: Setup, radius_px: float, edge_angle: float) -> float:
    """How far the edge would lie from its midpoint in light if its blur had acted on the encoded frame, pixels.

    A blur in light (defocus, the lens) leaves the midpoint in light where it
    was; a blur of the encoded frame (a camera's or codec's smoothing) moves
    it, the more the brighter the spot against the background. Which one acted
    the edge does not tell, so this is its uncertainty. The blur is the
    Gaussian that, acting on the encoded model edge (:func:`spotnav.optics.edgeblur.seen_edge`),
    makes it as wide as the edge measured (less ``_WIDTH_TOLERANCE_PX``, how
    well a width is measured); the shift is that model's. 0 for an edge no
    wider than the unblurred model's.
    """
    band = _soft_band_px(setup, radius_px, edge_angle) * (1.0 + _BAND_SLACK)
    if not np.isfinite(edge.plateau + edge.background) or not edge.plateau > edge.background:
        return 0.0
    width = edge.width_px - _WIDTH_TOLERANCE_PX
    unblurred = _unblurred_edge(round(band, 2))
    if not width > unblurred[0]:
        return 0.0
    light, values = response_curve(setup.camera.pixel_response)
    blur = frame_blur_for_width(edge.plateau, edge.background, band, width, light, values)
    return abs(frame_blur_shift(edge.plateau, edge.background, band, blur, light, values))


@lru_cache(maxsize=4096)
def _unblurred_edge(band_px: float) -> tuple[float, float]:
    """:func:`spotnav.optics.edgeblur.seen_edge` without a blur: the levels and the response do not matter then (cached
    by band)."""
    light, values = response_curve("linear")
    return seen_edge(1.0, 0.0, band_px, 0.0, light, values)


def _soft_band_px(setup: Setup, radius_px: float, edge_angle: float) -> float:
    """The widest soft band the beam may have, pixels: :func:`_soft_band_share` of the spot's radius."""
    return _soft_band_share(setup, edge_angle) * radius_px


@lru_cache(maxsize=32)
def _soft_band_share(setup: Setup, edge_angle: float) -> float:
    """The widest soft band the beam may have, as a share of the spot's radius (once per setup: every tracked frame
    asks).

    ``2 (outer - edge) / beta``, the band's outer side ``beta`` (or the edge
    plus half ``instrument.edge_band_deg``), with the edge as far inside as
    its uncertainty allows (``_EDGE_REACH`` sigma: a beam known to 0.3 deg may
    be that much softer), and at least the default edge model's (a
    calibrated edge may lie beyond beta).
    """
    instrument = setup.instrument
    beta = instrument.beam_half_angle
    outer = beta if instrument.edge_band_deg is None else edge_angle + 0.5 * np.radians(instrument.edge_band_deg)
    (edge,) = PARAMETER_GROUPS["edge-angle"]
    inner = edge_angle - _EDGE_REACH * np.sqrt(geometry_covariance(setup)[edge, edge])
    soft = max(outer - inner, beta - edge_angle_of_blend(beta, DEFAULT_BLEND))
    share: float = 2.0 * soft / beta
    return share


@dataclass(frozen=True)
class EdgeVerdict:
    """The judgement of one spot's edge (:func:`judge_edge`).

    Attributes
    ----------
    status : str
        ``ok``, or why the edge cannot be trusted: ``unreliable`` or ``blurred``
        (a :data:`~spotnav.pose.estimate.STATUSES` status).
    detail : str
        The reason, for a status other than ``ok``.
    sigma : float
        A trusted edge's own whole-edge sigma, radians (NaN otherwise).
    """

    status: str
    detail: str = ""
    sigma: float = float("nan")

    @property
    def ok(self) -> bool:
        """Whether the edge can be trusted."""
        return self.status == "ok"


def judge_edge(edge: SpotEdge, setup: Setup, radius_px: float, edge_angle: float) -> EdgeVerdict:
    """Whether a spot's edge can be trusted: its own whole-edge sigma (radians), or the status and reason it cannot.

    ``unreliable``: noise that biases the halfway level (contrast under
    ``_MIN_CONTRAST_TO_NOISE`` times the noise); too few points (under
    ``MIN_EDGE_POINTS`` or ``_MIN_EDGE_FRACTION`` of the rays); a plateau
    clipped at full scale in every channel (over ``_MAX_CLIPPED_FRACTION`` of
    it), which lowers that level and moves the edge outward. ``blurred``: a
    blur whose unknown kind may have moved the edge by more than
    ``_MAX_BLUR_MM`` of tip height (:func:`blur_shift_px`), whatever the
    spot's size; where the noise beside the spot told the blur of the encoded
    frame (:attr:`~spotnav.image.rays.SpotEdge.frame_shift_sigma_px`), its shift
    was taken out and only its uncertainty counts (twice its sigma; a
    clipped spot's flank was read with that blur in its model, and only the
    edge's curvature moved it). A trusted edge's sigma is half the shift that blur may have
    caused and, where the plateau clips, the shift the fitted amplitude's
    uncertainty leaves (:attr:`~spotnav.image.rays.SpotEdge.flank_shift_px`): a
    uniform shift of ``s`` pixels is an angle of about ``s`` over the spot's
    radius times the edge angle. A clipped plateau is refused only where the
    photometric model did not read it.
    """
    # Every tracked frame passes here: plain floats and math, and the reasons' text only where one is given.
    if math.isfinite(edge.contrast_to_noise) and not edge.contrast_to_noise >= _MIN_CONTRAST_TO_NOISE:
        ratio = f"{edge.contrast_to_noise:.0f} times the noise, under {_MIN_CONTRAST_TO_NOISE:.0f}"
        return EdgeVerdict("unreliable", f"the edge's contrast is {ratio}")
    if edge.clipped_fraction > _MAX_CLIPPED_FRACTION and not math.isfinite(edge.log_amplitude):
        clipped = f"{100 * edge.clipped_fraction:.0f} %"
        return EdgeVerdict(
            "unreliable",
            f"{clipped} of the spot inside its edge is at full scale in every channel, and the beam has no "
            "soft band to read its flank by",
        )
    if len(edge.pixels) < max(MIN_EDGE_POINTS, _MIN_EDGE_FRACTION * edge.rays):
        left_out = f", {edge.dark_rays} left out (vessels, the shaft, glints)" if edge.dark_rays else ""
        found = f"{len(edge.pixels)} of {edge.rays} rays found the edge{left_out}"
        return EdgeVerdict("unreliable", f"too few edge points: {found}")
    told = math.isfinite(edge.frame_shift_sigma_px)  # the noise beside the spot told the encoded frame's blur
    measured = told and math.isfinite(edge.frame_blur_px)  # else the edge was put halfway: half the shift either way
    if not told:
        shift = blur_shift_px(edge, setup, radius_px, edge_angle)
    else:
        shift = (2.0 if measured else 1.0) * edge.frame_shift_sigma_px
    height_mm = shift * _mm_per_px(setup) / (math.sin(edge_angle) * math.cos(edge_angle))
    if height_mm > _MAX_BLUR_MM:
        why = f"the edge is {edge.width_px:.1f} px wide"
        if measured:
            why += f" and the frame's blur after its encoding {edge.frame_blur_px:.1f} px (from its noise): that"
        else:
            why += ", blurred: where the blur acted" + (" (the noise does not tell)" if told else "")
        uncertain = f"{shift:.2f} px ({height_mm:.3f} mm of height) uncertain"
        return EdgeVerdict("blurred", f"{why} leaves it {uncertain}")
    sigma = edge.frame_shift_sigma_px if told else 0.5 * shift
    return EdgeVerdict("ok", sigma=float(np.hypot(sigma, edge.flank_shift_px)) * edge_angle / radius_px)


@lru_cache(maxsize=32)
def _mm_per_px(setup: Setup) -> float:
    """Millimetres on the retina per pixel near the pole (once per setup: every tracked frame asks)."""
    camera = setup.camera
    return float(camera_depth_mm(camera, np.zeros(3))) / camera.focal_px


def residuals_px(
    camera: Camera, points_in_eye: np.ndarray, tips_in_eye: np.ndarray, residuals: np.ndarray
) -> np.ndarray:
    """Angular residuals as pixels: each point's distance from its tip over its depth, times the focal length.

    Parameters
    ----------
    camera : Camera
    points_in_eye : ndarray, shape (..., 3)
        The edge points on the retina, mm.
    tips_in_eye : ndarray, shape (..., 3) or (3,)
        The tip of each point's frame, mm (broadcast to the points).
    residuals : ndarray, shape (...)
        Radians (broadcast to the points).

    Returns
    -------
    ndarray, shape (...)
        Pixels.

    Raises
    ------
    ValueError
        If the shapes do not match.
    """
    points = np.asarray(points_in_eye, dtype=float)
    if points.ndim == 0 or points.shape[-1] != 3:
        raise ValueError(f"points_in_eye must have shape (..., 3), got {points.shape}")
    shape = points.shape[:-1]
    tips, angles = np.asarray(tips_in_eye, dtype=float), np.asarray(residuals, dtype=float)
    if not (_broadcasts(tips.shape, points.shape) and _broadcasts(angles.shape, shape)):
        raise ValueError(
            f"tips_in_eye {tips.shape} and residuals {angles.shape} must match points_in_eye {points.shape}"
        )
    tips, angles = np.broadcast_to(tips, points.shape), np.broadcast_to(angles, shape)
    point_rows, tip_rows, angle_rows = [
        np.ascontiguousarray(values).reshape(-1, *values.shape[len(shape) :]) for values in (points, tips, angles)
    ]
    return _residuals_px(point_rows, tip_rows, angle_rows, *_depth_of(camera)).reshape(shape)


def _broadcasts(shape: tuple[int, ...], target: tuple[int, ...]) -> bool:
    """Whether an array of ``shape`` broadcasts to ``target`` (NumPy's rule: each trailing size 1 or the same)."""
    extra = len(target) - len(shape)
    return extra >= 0 and all(size in (1, wanted) for size, wanted in zip(shape, target[extra:], strict=True))


def _depth_of(camera: Camera) -> tuple[np.ndarray, float, float]:
    """What :func:`_residuals_px` needs of ``camera``: the optical axis (3,) in the eye frame, its offset and the
    focal length (pixels): a point's depth is ``axis @ point + offset`` (:func:`camera_depth_mm`)."""
    return camera.rotation_to_camera[2], float(camera.translation_to_camera_mm[2]), camera.focal_px


@njit(cache=True)
def _residuals_px(
    points: np.ndarray, tips: np.ndarray, residuals: np.ndarray, axis: np.ndarray, offset: float, focal_px: float
) -> np.ndarray:
    """:func:`residuals_px` of points (N, 3) from their tips (N, 3), compiled."""
    out = np.empty(len(points))
    for n in range(len(points)):
        dx, dy, dz = points[n, 0] - tips[n, 0], points[n, 1] - tips[n, 1], points[n, 2] - tips[n, 2]
        depth = axis[0] * points[n, 0] + axis[1] * points[n, 1] + axis[2] * points[n, 2] + offset
        out[n] = residuals[n] * np.sqrt(dx * dx + dy * dy + dz * dz) * focal_px / depth
    return out


@njit(cache=True)
def _harmonics(du: float, dv: float, out: np.ndarray) -> None:
    """``1, cos a, sin a, ..., cos Ka, sin Ka`` of the angle ``a`` of the offset ``(du, dv)`` into ``out`` (1 + 2K,),
    compiled: by the angle-sum recurrence from ``cos a`` and ``sin a``."""
    radius = np.hypot(du, dv)
    cos_a, sin_a = (du / radius, dv / radius) if radius > 0.0 else (1.0, 0.0)
    out[0] = 1.0
    cos_m, sin_m = 1.0, 0.0
    for m in range(1, (len(out) - 1) // 2 + 1):
        cos_m, sin_m = cos_m * cos_a - sin_m * sin_a, sin_m * cos_a + cos_m * sin_a
        out[2 * m - 1], out[2 * m] = cos_m, sin_m


@njit(cache=True)
def _spot_harmonics(points: np.ndarray) -> int:
    """How many harmonics of a spot's edge points (K, 3) on the retina (mm) a misfit may bend it by, compiled:
    those whose half period along the edge is ``_BEND_MM`` or longer (the shorter ones are the fundus's), at
    least ``_MIN_HARMONICS`` and at most ``_HARMONICS``."""
    centre = np.array([np.mean(points[:, 0]), np.mean(points[:, 1]), np.mean(points[:, 2])])
    radius = 0.0
    for n in range(len(points)):
        radius += np.sqrt(np.sum((points[n] - centre) ** 2)) / len(points)
    return min(max(int(np.pi * radius / _BEND_MM), _MIN_HARMONICS), _HARMONICS)


@njit(cache=True)
def _fit_spread(
    points: np.ndarray,
    tip: np.ndarray,
    residuals: np.ndarray,
    inliers: np.ndarray,
    spots: np.ndarray,
    pixels: np.ndarray,
    axis: np.ndarray,
    offset: float,
    focal_px: float,
) -> tuple[float, float, float, float]:
    """A one-frame fit's inliers' RMS residual in pixels and in radians, their fraction, and the RMS residual their
    noise explains (radians), compiled.

    ``points`` (N, 3) mm around one ``tip`` (3,); ``residuals`` (N,) radians; ``inliers`` (N,) bool; ``spots``
    (N,) each point's spot, each spot's points together; ``pixels`` (N, 2) the points in the image; the camera as
    :func:`_depth_of` gives it. A model that does not fit bends a spot's edge slowly, the points' noise from
    point to point (over a few pixels, more where the frame is blurred): the noise is what a Fourier series of
    harmonics in each point's angle about its spot's centre leaves of the residuals (:func:`_spot_harmonics` of
    them: the fundus's bends are noise too, and on a small spot they are slow). With no inlier the RMS values are
    NaN; without a spot of ``_MIN_NOISE_POINTS`` inliers, the noise.
    """
    tips = np.empty_like(points)
    tips[:] = tip
    pixels_off = _residuals_px(points, tips, residuals, axis, offset, focal_px)
    kept = np.flatnonzero(inliers)
    left, freedom = 0.0, 0
    first = 0
    while first < len(kept):
        last = first
        while last + 1 < len(kept) and spots[kept[last + 1]] == spots[kept[first]]:
            last += 1
        rows = kept[first : last + 1]
        first = last + 1
        if len(rows) < _MIN_NOISE_POINTS:
            continue
        # The series's least squares by its normal equations (at most 13 x 13), the harmonics by their recurrence.
        terms = 1 + 2 * _spot_harmonics(points[rows])
        centre_u, centre_v = np.mean(pixels[rows, 0]), np.mean(pixels[rows, 1])
        normal, right, basis = np.zeros((terms, terms)), np.zeros(terms), np.empty(terms)
        for n in rows:
            _harmonics(pixels[n, 0] - centre_u, pixels[n, 1] - centre_v, basis)
            for i in range(terms):
                right[i] += basis[i] * residuals[n]
                for j in range(i, terms):
                    normal[i, j] += basis[i] * basis[j]
        for i in range(terms):
            for j in range(i):
                normal[i, j] = normal[j, i]
        coefficients = np.linalg.solve(normal, right)
        for n in rows:
            _harmonics(pixels[n, 0] - centre_u, pixels[n, 1] - centre_v, basis)
            left += (residuals[n] - np.dot(basis, coefficients)) ** 2
        freedom += len(rows) - terms
    noise = np.sqrt(left / freedom) if freedom > 0 else np.nan
    return (
        np.sqrt(np.mean(pixels_off[kept] ** 2)),
        np.sqrt(np.mean(residuals[kept] ** 2)),
        len(kept) / max(len(inliers), 1),
        noise,
    )


class _FitFigures(TypedDict):
    """What :func:`judge_fit` carries to every estimate it makes (:class:`PoseEstimate`'s fields)."""

    spots: int
    rms_px: float
    fit_ratio: float
    sigma_mm: NotRequired[float]


def judge_fit(
    solution: ConeSolution,
    setup: Setup,
    *,
    spots: int,
    detail: str = "",
    other_axis: np.ndarray | None = None,
) -> PoseEstimate:
    """A one-frame cone fit as an estimate, or the reason it is refused.

    The fit tests itself first: its RMS residual over the one its points'
    noise explains (the estimate's ``fit_ratio``). Over
    :data:`MAX_FIT_RATIO` no noise explains the residuals: ``mismatch``, the
    setup's light or geometry is not this frame's (or the frame is disturbed
    as no model here says), and the detail names what a free edge angle would
    fit. Over :data:`FIT_RATIO_EXPLAINED` the excess counts as a shift of each
    spot's whole edge (:meth:`~spotnav.pose.conefit.solution.ConeSolution.with_edge_shift`),
    which widens ``sigma_mm``. Then ``uncalibrated`` when the setup's stated
    geometry uncertainty takes the tip's uncertainty over
    :data:`MAX_SIGMA_MM` (a geometry that uncertain may also cause any other
    problem, which the detail adds); ``mismatch`` where the widening does for
    three beams (one beam's excess this small the fundus under its edge may
    cause as well: ``unreliable``, and the detail says both);
    else ``unreliable`` when the fit fails a
    consistency check (too few inliers, a residual too large in both degrees
    and pixels, its own tip uncertainty over that limit, a tip outside the
    eye). The estimate's ``sigma_mm`` carries the geometry's uncertainty.

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
    points = solution.problem.points
    rms_px, rms_rad, inlier_fraction, noise_rad = _fit_spread(
        solution.problem.points_in_eye,
        tip,
        solution.residuals,
        solution.inliers,
        points.spot,
        points.pixels,
        *_depth_of(setup.camera),
    )
    fit_ratio = rms_rad / noise_rad if noise_rad > 0.0 else float("nan")
    common: _FitFigures = {"spots": spots, "rms_px": rms_px, "fit_ratio": fit_ratio}
    problems = []  # a fit these make no use of, whatever its residuals say of the setup
    if inlier_fraction < _MIN_INLIER_FRACTION:
        problems.append(f"only {100 * inlier_fraction:.0f} % of the edge fits the cones")
    if not setup.contains_point(tip):
        problems.append("the fitted tip lies outside the eye")
    if not solution.settled:
        problems.append("the fitted tip is held at the edge of its 2 mm box")
    structural = bool(problems)
    if fit_ratio > MAX_FIT_RATIO and not structural:
        return PoseEstimate("mismatch", detail=_mismatch(solution, setup, rms_rad, noise_rad), **common)
    stated_own, stated = solution.tip_sigma_mm(geometry=False), solution.tip_sigma_mm()  # the setup's uncertainty
    if FIT_RATIO_EXPLAINED < fit_ratio <= MAX_FIT_RATIO:
        solution = solution.with_edge_shift(float(np.sqrt(rms_rad**2 - (FIT_RATIO_EXPLAINED * noise_rad) ** 2)))
    rms_deg = float(np.degrees(rms_rad))
    own_sigma, sigma = solution.tip_sigma_mm(geometry=False), solution.tip_sigma_mm()
    if rms_deg > MAX_RMS_DEG and rms_px > MAX_RMS_PX:
        problems.append(f"RMS residual {rms_deg:.3f} deg ({rms_px:.2f} px)")
    if own_sigma > MAX_SIGMA_MM:
        problems.append(f"tip uncertainty {own_sigma:.3f} mm")
    common["sigma_mm"] = sigma
    if stated > MAX_SIGMA_MM >= stated_own:  # a geometry this uncertain may also explain any other problem
        if fit_ratio > FIT_RATIO_EXPLAINED:
            problems.append(f"edge RMS {fit_ratio:.1f} times what the noise explains")
        return PoseEstimate("uncalibrated", detail="; ".join([_geometry_blame(solution, sigma), *problems]), **common)
    if FIT_RATIO_EXPLAINED < fit_ratio and sigma > MAX_SIGMA_MM >= stated and not structural:  # the misfit did
        if setup.instrument.beam_count > 1:  # three beams' edges bend alike where the light is not the setup's
            why = f"{_mismatch(solution, setup, rms_rad, noise_rad)}; it leaves the tip uncertain by {sigma:.3f} mm"
            return PoseEstimate("mismatch", detail=why, **common)
        # One beam's excess under MAX_FIT_RATIO does not say which: the fundus under its edge bends it as well.
        problems.append(
            f"edge RMS {fit_ratio:.1f} times what the noise explains, which leaves the tip uncertain by {sigma:.3f} "
            "mm: the fundus under the edge (spotnav show), or a setup unlike this frame (spotnav calibrate)"
        )
    if problems:
        return PoseEstimate("unreliable", detail="; ".join(problems), **common)
    return PoseEstimate(
        "ok", tip_in_eye=tip, axis=solution.axis(), roll=solution.roll(), other_axis=other_axis, detail=detail, **common
    )


def _mismatch(solution: ConeSolution, setup: Setup, rms_rad: float, noise_rad: float) -> str:
    """Why a fit's residuals are more than its noise: what did not fit, and what calibrates it.

    Three beams' cones are fitted again with their edge angle free (one
    beam's angle trades with its height: a frame does not tell it); where
    that fit's residuals are ones the noise explains, the detail gives the
    angle the frame shows.
    """
    residual = f"edge RMS {np.degrees(rms_rad):.3f} deg where the noise explains {np.degrees(noise_rad):.3f}"
    if setup.instrument.beam_count > 1:
        (edge,) = PARAMETER_GROUPS["edge-angle"]
        points = solution.problem.points
        tip, axis, roll = solution.tip(), solution.axis(), solution.roll()
        free = cone_problem(setup, points, tip[None], axis[None], np.array([roll]), free_shared=(edge,))
        refit = fit_cones(free)
        camera = _depth_of(setup.camera)
        _, rms_free, _, noise_free = _fit_spread(
            free.points_in_eye, refit.tip(), refit.residuals, refit.inliers, points.spot, points.pixels, *camera
        )
        if rms_free <= FIT_RATIO_EXPLAINED * noise_free:
            stated = np.degrees(edge_angle(setup))
            fitted = stated + np.degrees(refit.shared[edge])
            return (
                f"the light's cone does not fit this frame: {residual}; its edge fits at {fitted:.2f} deg where the "
                f"setup says {stated:.2f}: calibrate the edge angle (spotnav calibrate --fit edge-angle)"
            )
    tried = ", and no edge angle fits it" if setup.instrument.beam_count > 1 else ""
    return (
        f"the setup does not fit this frame: {residual}{tried}; calibrate the geometry (spotnav calibrate), or see "
        "what disturbs the spot (spotnav show)"
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
