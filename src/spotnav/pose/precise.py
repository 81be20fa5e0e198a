"""spotnav's precise method: sub-pixel edges and one fit of the light cones on the sphere (``docs/methods.md``).

The thesis's closed form (:mod:`spotnav.pose.thesis`) finds the spots, which beam
made each and a starting pose. Each spot's edge is then located to a fraction
of a pixel (:func:`spotnav.image.rays.detect_edge_subpixel`), and one instrument
pose is fitted to every edge point through the camera and the edge model
(:mod:`spotnav.pose.conefit`), leaving out what the shaft hides
(:mod:`spotnav.pose.shaft`). The estimate carries its 1-sigma tip uncertainty,
the setup's geometry uncertainty included, and is judged by
:func:`spotnav.pose.checks.judge_fit`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from spotnav.image.fragments import group_fragments, outer_boundary
from spotnav.image.spots import SpotDetection, detect_spots_otsu
from spotnav.optics.camera import camera_depth_mm
from spotnav.pose.checks import check_image_size, judge_fit
from spotnav.pose.conefit.parameters import PARAMETER_GROUPS
from spotnav.pose.conefit.solution import ConeSolution
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.pipeline import (
    LightReading,
    SpotPlan,
    fit_visible,
    fitted_edges_px,
    plan_found_spots,
    read_light,
    refit_free_axis,
)
from spotnav.pose.shaft import hidden_by_shaft, visible_edge_points
from spotnav.pose.thesis import ThesisSolution, solve_thesis
from spotnav.setup.config import Setup
from spotnav.setup.geometry import BeamAssignment, angles_between, assign_beams, normalize
from spotnav.setup.sections import check_localized_beams

__all__ = [
    "EdgeFrame",
    "PreciseResult",
    "detect_spots",
    "keep_beam_spots",
    "largest_spot_area_px",
    "localize_precise",
    "localize_precise_with_edges",
    "plan_spots",
    "prepare_edges",
    "smallest_spot_area_px",
]

_PRECISE_CONTRAST_SIGMA = 4.0
_FRAGMENT_AREA_FRACTION = 0.005  # regions this small beside the largest may still be a piece of a spot
_VESSEL_MM = 0.3  # the widest gap vessels (two side by side) may cut in a spot: fragments closer may be one spot
_COARSE_BLUR_PX = 5  # the coarse detection's blur widens a vessel's gap by about its kernel (shrunk pixels) ...
_SHRUNK_BLUR_PX = 3  # ... a shrunk frame, already averaged over its cells, needs less
_MIN_SPOT_RADIUS_PX = 12.0  # the smallest spot keeps this radius in the shrunk image the outlines are drawn on
_FIND_SPOT_RADIUS_PX = 3.0  # ... and this radius in the shrunk image the spots are found on (by default)
_MAX_CLUTTER_AREA = 0.25
_MIN_TIP_HEIGHT_MM = 1.0  # the lowest tip considered: its spot is the smallest
_MAX_TIP_HEIGHT_MM = 10.0  # the highest: its spot is the largest
_BACKGROUND_SPOTS = 3.0  # a background broader than this many of the largest spot's radii is not a spot
_MIRROR_RESIDUAL_RATIO = 1.1
_MIRROR_DISTANCE_MM = 0.1
# A frame's fit gains little from more rays per spot: most of the error left is each spot's whole-edge shift, which
# no number of rays averages away (docs/methods.md: 5 % of the mean error on the quick paths, one beam, for a
# quarter to a third of the time). Calibration, which pools its frames' edges into the geometry, reads one per pixel.
_MAX_RAYS = 256
_SHAFT_MARGINS_MM = (0.05, 0.2)  # edge points this close to the shaft's outline are left out too
_SHAFT_PASSES = 3
# Three beams show the axis: refused when it misses the insertion line by this many sigmas (and this many degrees).
_MISCALIBRATION_SIGMAS = 5.0
_MIN_MISCALIBRATION_DEG = 1.0  # a free axis errs by up to 0.6 deg on the thesis world at 1024 px


@dataclass(frozen=True)
class EdgeFrame:
    """One frame's material for the precise fit: the find stage's plan, its spots' light read, and the thesis's start;
    or why the frame gives none.

    Attributes
    ----------
    start : PoseEstimate
        The thesis's closed form the fit starts from (``ok``); or why the frame
        gives no edges to fit (not ``ok``: the thesis's own refusal,
        ``ambiguous`` beams, or the light read's ``unreliable`` or ``blurred``),
        and then the other fields are None.
    plan : SpotPlan or None
        Where each spot's edge is read, and its beam (:func:`plan_spots`).
    reading : LightReading or None
        Each spot's sub-pixel edge, its own whole-edge sigma and its beam (:func:`prepare_edges`; None before the
        light is read).
    axis : ndarray, shape (3,), or None
        Starting instrument axis.
    roll : float
        Starting roll, radians.
    solution : ThesisSolution or None
        The thesis's reconstruction it started from.
    """

    start: PoseEstimate
    plan: SpotPlan | None = None
    reading: LightReading | None = None
    axis: np.ndarray | None = None
    roll: float = 0.0
    solution: ThesisSolution | None = None

    @property
    def ok(self) -> bool:
        """Whether the frame gives a start to fit from."""
        return self.start.ok

    @property
    def edges_px(self) -> tuple[np.ndarray, ...]:
        """Each spot's sub-pixel edge points, in order around it, pixels, shapes (N_k, 2)."""
        return self._read().edges_px

    @property
    def edge_sigmas(self) -> tuple[float, ...]:
        """Each spot's own whole-edge uncertainty, radians."""
        return self._read().sigmas

    @property
    def beams(self) -> tuple[int, ...]:
        """The beam that made each spot."""
        return self._read().beams

    def _read(self) -> LightReading:
        """The light read; before it is, :class:`AttributeError` (a bug in the caller), as reading None's would."""
        if self.reading is None:
            raise AttributeError("the frame's light is not read yet")
        return self.reading


def detect_spots(image: np.ndarray, setup: Setup, find_radius_px: float = _FIND_SPOT_RADIUS_PX) -> SpotDetection:
    """The coarse detection of the precise methods: fainter spots than the thesis's, fragments grouped into spots.

    A background broader than any spot (an endo-illuminator's glow) is
    removed; regions down to ``_FRAGMENT_AREA_FRACTION`` of the largest are kept, then
    those closer than a vessel's width (``_VESSEL_MM``) are grouped by the
    ellipse their outer boundaries share
    (:func:`spotnav.image.fragments.group_fragments`): the pieces of a spot that dark
    vessels cut are one spot, and two spots stay two.

    Parameters
    ----------
    image : ndarray
        The frame (see :func:`spotnav.image.spots.detect_spots_otsu`).
    setup : Setup
        Its camera (response, focal length) and beam: how small a spot can be.
    find_radius_px : float
        The spots are found on the frame shrunk as far as leaves the smallest spot's radius this many pixels
        (:func:`detection_decimation`); their outlines are drawn again where it leaves ``_MIN_SPOT_RADIUS_PX``.

    Returns
    -------
    SpotDetection
    """
    decimate, find, background_px, gap_px = _detection_scales(setup, find_radius_px)
    detection = detect_spots_otsu(
        image,
        blur_px=_blur_px(find),
        min_contrast_sigma=_PRECISE_CONTRAST_SIGMA,
        response=setup.camera.pixel_response,
        min_area_fraction=_FRAGMENT_AREA_FRACTION,
        background_px=background_px,
        decimate=find,
        refine=(decimate, _blur_px(decimate)),
    )
    return group_fragments(detection, image.shape[:2], gap_px, smallest_spot_area_px(setup))


@lru_cache(maxsize=32)
def _detection_scales(setup: Setup, find_radius_px: float) -> tuple[int, int, int, float]:
    """:func:`detect_spots`' scales, computed once per setup: the decimations the outlines are drawn at and the
    spots found at, the background's disc (pixels) and the widest gap between a spot's fragments (pixels: a
    vessel's, widened by the outlines' blur)."""
    decimate = detection_decimation(setup)
    camera = setup.camera
    vessel_px = _VESSEL_MM * camera.focal_px / float(camera_depth_mm(camera, np.zeros(3)))
    return (
        decimate,
        detection_decimation(setup, find_radius_px),
        int(_BACKGROUND_SPOTS * np.sqrt(largest_spot_area_px(setup) / np.pi)),
        vessel_px + _blur_px(decimate) * decimate,
    )


def _blur_px(decimate: int) -> int:
    """The blurs' kernel on a frame shrunk by ``decimate``: ``_COARSE_BLUR_PX``, less once the cells average."""
    return _COARSE_BLUR_PX if decimate == 1 else _SHRUNK_BLUR_PX


def detection_decimation(setup: Setup, min_radius_px: float = _MIN_SPOT_RADIUS_PX) -> int:
    """How much the coarse detection shrinks the frame: the largest power of two that leaves the smallest spot's
    radius ``min_radius_px`` (1 for small frames). The outlines are drawn at ``_MIN_SPOT_RADIUS_PX``; the spots are
    found at ``detect_spots``' ``find_radius_px``."""
    radius_px = np.sqrt(smallest_spot_area_px(setup) / np.pi)
    return int(2 ** max(np.floor(np.log2(radius_px / min_radius_px)), 0))


def largest_spot_area_px(setup: Setup) -> float:
    """Area of the largest spot a beam makes with the tip ``_MAX_TIP_HEIGHT_MM`` above the retina, pixels."""
    return smallest_spot_area_px(setup) * (_MAX_TIP_HEIGHT_MM / _MIN_TIP_HEIGHT_MM) ** 2


@lru_cache(maxsize=32)
def smallest_spot_area_px(setup: Setup) -> float:
    """Area of the smallest spot a beam makes with the tip ``_MIN_TIP_HEIGHT_MM`` above the retina, pixels
    (computed once per setup).

    A bright region this large may be a spot: it is never dismissed as clutter.
    """
    camera = setup.camera
    depth = float(camera_depth_mm(camera, np.zeros(3)))
    radius_px = _MIN_TIP_HEIGHT_MM * np.tan(setup.instrument.beam_half_angle) * camera.focal_px / depth
    return float(np.pi * radius_px**2)


@dataclass(frozen=True)
class PreciseResult:
    """The precise method's answer for one frame, and what it came from.

    Attributes
    ----------
    estimate : PoseEstimate
    edges : EdgeFrame or None
        The sub-pixel edges and the start the fit began from; None when the
        frame gave no edges to fit (see ``estimate.status``).
    fit : ConeSolution or None
        The cone fit the estimate reports (its points, residuals, inliers and
        covariance); None when no fit ran to the end.
    """

    estimate: PoseEstimate
    edges: EdgeFrame | None = None
    fit: ConeSolution | None = None

    @property
    def fitted_edges_px(self) -> tuple[np.ndarray, ...]:
        """The edge points the fit used, per spot, pixels, shapes (N_k, 2); empty without a fit."""
        return () if self.fit is None else fitted_edges_px(self.fit)


def localize_precise(image: np.ndarray, setup: Setup, *, through_insertion: bool = True) -> PoseEstimate:
    """spotnav's precise method (see :func:`localize_precise_with_edges`)."""
    return localize_precise_with_edges(image, setup, through_insertion=through_insertion).estimate


def keep_beam_spots(detection: SpotDetection, setup: Setup) -> tuple[SpotDetection, str]:
    """The spots the beams made: the detection without the small clutter beyond ``beam_count`` spots.

    Returns
    -------
    SpotDetection
        The detection, its spots at most ``beam_count`` (unchanged when ambiguous).
    str
        Why the spots are ambiguous (more spots than beams, the extra one too large to be clutter), or ``""``.
    """
    beams = setup.instrument.beam_count
    spots = detection.spots
    if len(spots) <= beams:
        return detection, ""
    extra = spots[beams].area_px
    if extra > _MAX_CLUTTER_AREA * spots[beams - 1].area_px or extra >= smallest_spot_area_px(setup):
        return detection, f"{detection.regions}, {beams} beam{'s' if beams > 1 else ''}: more spots than beams"
    return replace(detection, spots=spots[:beams]), ""


def localize_precise_with_edges(
    image: np.ndarray,
    setup: Setup,
    *,
    through_insertion: bool = True,
    max_rays: int = _MAX_RAYS,
    find_radius_px: float = _FIND_SPOT_RADIUS_PX,
) -> PreciseResult:
    """spotnav's precise method (the module's docstring), with the edges and the fit it came from.

    The coarse detection accepts fainter spots than the thesis's; more bright
    regions than beams are ``ambiguous`` unless the extra ones are less than a
    quarter of the size of the smallest spot kept and smaller than any spot
    can be (:func:`smallest_spot_area_px`): clutter such as glints.

    Parameters
    ----------
    image : ndarray
        Camera frame, sRGB-encoded, 8 or 16 bits.
    setup : Setup
        Only ``eye``, ``camera``, ``instrument`` and how well they are known are used.
    through_insertion : bool
        Constrain the axis through the insertion point (3 unknowns for one
        beam, 4 with the roll for three); ``False`` fits the axis too.
    max_rays : int
        Most rays per spot's edge (one per pixel of its outline up to this; at least 64).
    find_radius_px : float
        The smallest spot's radius on the shrunk frame the spots are found on (:func:`detect_spots`).

    Returns
    -------
    PreciseResult

    Raises
    ------
    SetupError
        For 2 or 4 beams (simulation only, :func:`~spotnav.setup.sections.check_localized_beams`).
    """
    check_localized_beams(setup.instrument)
    wrong = check_image_size(image, setup)
    if wrong is not None:
        return PreciseResult(wrong)
    found = detect_spots(image, setup, find_radius_px)
    detection, ambiguous = keep_beam_spots(found, setup)
    if ambiguous:
        return PreciseResult(PoseEstimate("ambiguous", spots=len(found.spots), detail=ambiguous))
    prepared = prepare_edges(image, detection, setup, through_insertion, max_rays)
    if not prepared.ok:
        return PreciseResult(prepared.start)
    estimate, fit = _fit_precise(prepared, setup, through_insertion)
    if estimate.ok and len(found.spots) > len(detection.spots):
        ignored = f"{len(found.spots) - len(detection.spots)} much smaller bright regions ignored"
        estimate = replace(estimate, detail="; ".join(filter(None, [estimate.detail, ignored])))
    return PreciseResult(estimate, prepared, fit)


def prepare_edges(
    image: np.ndarray, detection: SpotDetection, setup: Setup, through_insertion: bool, max_rays: int = _MAX_RAYS
) -> EdgeFrame:
    """The precise method up to its fit: the find stage (:func:`plan_spots`), then the spots' light read
    (:func:`spotnav.pose.pipeline.read_light`).

    A frame that cannot be used has a ``start`` that is not ``ok``, with the reason.
    """
    planned = plan_spots(detection, setup, through_insertion, max_rays)
    if not planned.ok:
        return planned
    if planned.plan is None:  # impossible: plan_spots plans every frame it passes
        raise RuntimeError("a planned frame without its plan")
    reading = read_light(image, setup, planned.plan)
    if isinstance(reading, PoseEstimate):
        return EdgeFrame(replace(reading, spots=planned.start.spots))
    return replace(planned, reading=reading)


def plan_spots(detection: SpotDetection, setup: Setup, through_insertion: bool, max_rays: int = _MAX_RAYS) -> EdgeFrame:
    """The precise method's find stage: the spots' rays (at most ``max_rays`` each), the beam of each and the
    light's pose from the thesis's closed form; with the thesis's solution, the starting axis and roll (an
    :class:`EdgeFrame` whose light is not read yet).

    Its ``start`` is ``ambiguous`` (which beam made each spot is not told) or the thesis's own refusal when the
    frame cannot be used.
    """
    plain = _without_height_correction(setup)
    # Start from the spots' convex outlines: the shaft or a vessel in front of a spot carves into it.
    detection = replace(detection, spots=tuple(outer_boundary(spot) for spot in detection.spots))
    solution = solve_thesis(detection, plain)
    start = solution.estimate
    if not start.ok:
        return EdgeFrame(start)
    axis = start.pose()[1]
    chosen_axes = np.array([c.cone_axes[i] for c, i in zip(solution.candidates, solution.chosen, strict=True)])
    if not through_insertion and len(solution.candidates) == 3:
        # Three symmetric beam axes sum along the instrument's axis, wherever the insertion point is.
        axis = normalize(chosen_axes.sum(axis=0))
    one_beam = BeamAssignment("ok", (0,), 0.0)
    assignment = one_beam if setup.instrument.beam_count == 1 else assign_beams(chosen_axes, axis)
    if not assignment.ok:
        detail = "cannot tell which spot each beam made"
        return EdgeFrame(PoseEstimate(assignment.status, spots=start.spots, detail=detail))
    beams, roll = list(assignment.beams), assignment.roll
    plan = plan_found_spots(setup, solution.spots, beams, start.pose()[0], axis, roll, max_rays)
    return EdgeFrame(start, plan=plan, axis=axis, roll=roll, solution=solution)


@lru_cache(maxsize=32)
def _without_height_correction(setup: Setup) -> Setup:
    """``setup`` with ``instrument.height_correction`` 1 (once per setup: a new setup is checked as it is built)."""
    return replace(setup, instrument=replace(setup.instrument, height_correction=1.0))


@dataclass(frozen=True)
class _ShaftView:
    """A pose :func:`_fit_unhidden` passed, and the edge points the shaft hid there (per spot)."""

    tip_in_eye: np.ndarray
    axis: np.ndarray
    hidden: list[np.ndarray]


def _fit_unhidden(
    prepared: EdgeFrame, setup: Setup, margin_mm: float
) -> tuple[ConeSolution, list[_ShaftView]] | PoseEstimate:
    """The fit through the insertion point to the edge the shaft leaves visible (its problem's points), and each
    pose at which the hidden points were found, with them.

    Which points the shaft hides depends on the pose: they are found again at
    each fitted pose until they stop changing (at most ``_SHAFT_PASSES``
    fits; the first fit uses every point if the start's shaft would hide too
    many). ``occluded`` when the shaft hides too much of a spot's edge at a
    fitted pose.
    """
    (tip, axis), roll = prepared.start.pose(), prepared.roll
    edges_px = prepared.edges_px
    hidden = hidden_by_shaft(setup, edges_px, tip, axis, margin_mm)
    views = [_ShaftView(tip, axis, hidden)]
    if not visible_edge_points(setup, edges_px, hidden).ok:  # judge the shaft at a fitted pose
        hidden = [np.zeros(len(edge), dtype=bool) for edge in edges_px]
    for _ in range(_SHAFT_PASSES):
        fitted = fit_visible(setup, prepared._read(), hidden, tip, axis, roll)
        if isinstance(fitted, PoseEstimate):
            return fitted
        fit = fitted
        tip, axis, roll = fit.tip(), fit.axis(), fit.roll()
        now_hidden = hidden_by_shaft(setup, edges_px, tip, axis, margin_mm)
        views.append(_ShaftView(tip, axis, now_hidden))
        if _same_hidden(hidden, now_hidden):
            break
        hidden = now_hidden
    return fit, views


def _hides_alike(setup: Setup, edges_px: Sequence[np.ndarray], views: list[_ShaftView], margin_mm: float) -> bool:
    """Whether a shaft band ``margin_mm`` wide hides the same points as the views' at each of their poses: a fit
    with that band would repeat theirs."""
    return all(
        _same_hidden(view.hidden, hidden_by_shaft(setup, edges_px, view.tip_in_eye, view.axis, margin_mm))
        for view in views
    )


def _same_hidden(hidden: Sequence[np.ndarray], other: Sequence[np.ndarray]) -> bool:
    """Whether two lists of hidden-point masks (one per spot) are equal."""
    return all(np.array_equal(a, b) for a, b in zip(hidden, other, strict=True))


def _fit_precise(
    prepared: EdgeFrame, setup: Setup, through_insertion: bool
) -> tuple[PoseEstimate, ConeSolution | None]:
    """The pose from the prepared edges, and the fit it comes from (None when none ran to the end)."""
    start = prepared.start
    # Leave out the edge the shaft hides; if the fit fails its checks, leave out a wider band around it (unless
    # that band hides no more points at any pose the fit passed: the fit would be the same).
    views: list[_ShaftView] = []
    for margin_mm in _SHAFT_MARGINS_MM:
        if views and _hides_alike(setup, prepared.edges_px, views, margin_mm):
            continue
        unhidden = _fit_unhidden(prepared, setup, margin_mm)
        if isinstance(unhidden, PoseEstimate):
            return unhidden, None
        constrained, views = unhidden
        verdict = judge_fit(constrained, setup, spots=start.spots, detail=start.detail)
        if verdict.status != "unreliable":
            break
    if through_insertion and not verdict.ok:
        return verdict, constrained  # refused: no cross-check to carry
    # The cross-check continues from the constrained fit and finds its own inliers: those of the constrained fit
    # leave out the arc a miscalibrated axis misses, which would hide it. Its points are the constrained fit's own.
    # Gauss-Newton's few steps from there: three beams' free axis within 0.005 deg of the converged fit; one beam's,
    # loose (its sigma some 0.3 deg), 0.04 deg from it on average and at most 1.2 of its sigmas (60 helix frames),
    # as far from the truth. precise-free answers with the free fit: Levenberg-Marquardt settles it.
    free = refit_free_axis(setup, constrained, "gauss-newton" if through_insertion else "levenberg-marquardt")
    if through_insertion:
        return _check_insertion(replace(verdict, other_axis=free.axis()), constrained, free, setup), constrained
    return _fit_free(prepared, setup, constrained, free)


def _fit_free(
    prepared: EdgeFrame, setup: Setup, constrained: ConeSolution, free: ConeSolution
) -> tuple[PoseEstimate, ConeSolution | None]:
    """``precise-free``: the axis fitted too, from the free fit and (one beam) both mirror-image starts.

    A cone and its mirror image fit one contour almost equally; ``ambiguous`` when they do.
    """
    start = prepared.start
    if prepared.solution is None or prepared.axis is None:  # impossible: plan_spots sets both on the frames it passes
        raise RuntimeError("a planned frame without its thesis solution or starting axis")
    # The shaft runs along the free axis (which the constrained fit does not know, off the insertion line).
    hidden = hidden_by_shaft(setup, prepared.edges_px, free.tip(), free.axis())
    starts = [(free.tip(), free.axis(), free.roll())]
    if setup.instrument.beam_count == 1:
        candidates = prepared.solution.candidates[0]
        mirrors = zip(candidates.apexes, candidates.cone_axes, strict=True)
        starts += [(apex, cone_axis, 0.0) for apex, cone_axis in mirrors]
    else:
        starts.append((start.pose()[0], prepared.axis, prepared.roll))
    fits = []
    for tip, axis, roll in starts:
        fit = fit_visible(setup, prepared._read(), hidden, tip, axis, roll, through_insertion=False)
        if isinstance(fit, PoseEstimate):
            return fit, None
        fits.append(fit)
    inside = sorted(
        (f for f in fits if setup.contains_point(f.tip())), key=lambda f: float(np.mean(np.abs(f.residuals)))
    )
    if not inside:
        return PoseEstimate("unreliable", spots=start.spots, detail="every fitted tip lies outside the eye"), None
    best = inside[0]
    for other in inside[1:]:
        close_fit = np.mean(np.abs(other.residuals)) < _MIRROR_RESIDUAL_RATIO * np.mean(np.abs(best.residuals))
        if close_fit and np.linalg.norm(other.tip() - best.tip()) > _MIRROR_DISTANCE_MM:
            detail = "a cone and its mirror image fit alike: fix the axis by the insertion point (method precise)"
            return PoseEstimate("ambiguous", spots=start.spots, detail=detail), best
    return judge_fit(best, setup, spots=start.spots, detail=start.detail, other_axis=constrained.axis()), best


def _check_insertion(
    estimate: PoseEstimate, constrained: ConeSolution, free: ConeSolution, setup: Setup
) -> PoseEstimate:
    """An ``ok`` estimate, or ``miscalibrated`` when three beams show an axis that misses the insertion line by more
    than its uncertainty.

    The free axis's uncertainty comes from its fit (angles about ``y`` and
    ``z``); the constrained axis's from the tip's own and the insertion point's.
    """
    if setup.instrument.beam_count == 1:
        return estimate
    angle = float(angles_between(free.axis(), constrained.axis()))
    about = free.frame_covariance((3, 4))
    free_variance = about[0, 0] + np.sin(free.frames[0, 3]) ** 2 * about[1, 1]
    insertion = PARAMETER_GROUPS["insertion-point"]
    insertion_variance = np.trace(constrained.problem.prior[np.ix_(insertion, insertion)])
    length = float(np.linalg.norm(constrained.tip() - constrained.insertion_in_eye))
    # Two of each point's three directions turn the line: the angle's variance over both components.
    tip_variance = np.trace(constrained.tip_covariance(geometry=False))
    line_variance = 2.0 / 3.0 * (tip_variance + insertion_variance) / length**2
    sigma = float(np.sqrt(free_variance + line_variance))
    if angle > max(_MISCALIBRATION_SIGMAS * sigma, np.radians(_MIN_MISCALIBRATION_DEG)):
        detail = (
            f"the beams show an axis {np.degrees(angle):.2f} deg from the line through the insertion point "
            f"({np.degrees(angle) / max(np.degrees(sigma), 1e-9):.0f} sigma): the insertion point or the camera "
            "is not where the setup says (calibrate)"
        )
        return replace(estimate, status="miscalibrated", tip_in_eye=None, axis=None, other_axis=None, detail=detail)
    return estimate
