"""Localize the instrument tip in one camera frame.

Methods (:data:`METHODS`): ``thesis`` (the thesis's Algorithms 1 and 2),
``precise`` (the default: sub-pixel edges and a direct cone fit with the axis
through the insertion point) and ``precise-free`` (the axis fitted too); see
``docs/methods.md``. Every method returns a :class:`PoseEstimate`: a pose with
status ``ok``, or a status that says why there is none. No method makes up a pose.

Statuses
--------
``ok``
    A pose was found.
``no_spot``
    No spot stands out from the background.
``ambiguous``
    More spots than beams, spots that match no beam order, or (``precise-free``,
    one beam) a cone and its mirror image that fit alike.
``too_few_spots``
    Fewer whole spots than the method needs (three beams need two).
``clipped``
    A spot reaches the image's border or leaves the retina.
``wrong_size``
    The image is not the camera's size.
``unreliable``
    A fit was found but fails a consistency check (see ``detail``).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from spotnav.camera import pixels_behind_segment, unproject_pixels_to_plane, unproject_pixels_to_sphere
from spotnav.config import Setup
from spotnav.detect import Spot, SpotDetection, SpotEdge, detect_edge_subpixel, detect_spots_otsu, outer_boundary
from spotnav.geometry import assign_beams, edge_angle_of_blend, normalize
from spotnav.reconstruct import (
    ConeCandidates,
    ConeFit,
    apex_candidates,
    choose_by_insertion,
    fit_cones,
    sphere_normal,
)

__all__ = [
    "METHODS",
    "MIN_EDGE_POINTS",
    "STATUSES",
    "EdgeFrame",
    "PoseEstimate",
    "check_image_size",
    "edge_half_angle",
    "edge_model_options",
    "edge_problem",
    "fit_height_correction",
    "hidden_by_shaft",
    "judge_fit",
    "localize",
    "localize_precise",
    "localize_precise_with_edges",
    "localize_thesis",
    "locate_from_spots",
    "smallest_spot_area_px",
    "spot_candidates",
    "visible_edge_points",
]

DEFAULT_BLEND = 0.15  # Blender's default spot_blend: the edge model when the setup gives none
MIN_EDGE_POINTS = 20
_MIN_INLIER_FRACTION = 0.5
# A fit is poor when its edge points lie both this far in angle (some 0.015 deg on a textured retina at 1 W)
# and this far in pixels (some 0.3 px from noise; at most 0.75 px on the frames the fault study accepts at
# 1024 px, 1.4 px for a pose off the insertion line forced through it) from their cones.
_MAX_RMS_DEG = 0.1
_MAX_RMS_PX = 1.0
_PRECISE_CONTRAST_SIGMA = 4.0
_MAX_CLUTTER_AREA = 0.25
_MIN_TIP_HEIGHT_MM = 1.0  # the lowest tip considered: its spot is the smallest
_MIN_CONTRAST_TO_NOISE = 20.0  # measured: 60-500 on good frames, 5-10 where heavy noise biased the edge by 0.1 mm
_EDGE_WIDTH_SLACK_PX = 4.0  # measured: widths at most 0.86 of band + 4 px unblurred, 1.1-2 with a 1.5 % motion blur
_MAX_CLIPPED_FRACTION = 0.5  # measured: 0.9-1.0 at +4 stops (edge 0.08-0.1 mm off), mostly under 0.1 at +2 stops
_MIRROR_RESIDUAL_RATIO = 1.1
_MIRROR_DISTANCE_MM = 0.1
# Added to sigma: the edge model's uncertainty (shared by all spots) and the shift of one spot's whole edge by the
# texture and vessels under it (each spot its own; some 0.006-0.0095 deg rms over the 5000 px paths at 1-2 W).
EDGE_MODEL_SIGMA = float(np.radians(0.003))
EDGE_CONTOUR_SIGMA = float(np.radians(0.007))
_MAX_SIGMA_MM = 0.03
_SHAFT_MARGINS_MM = (0.05, 0.2)  # edge points this close to the shaft's outline are left out too
_MAX_HIDDEN_FRACTION = 0.6  # a spot whose edge the shaft hides more than this is occluded
_SHAFT_PASSES = 3

STATUSES = (
    "ok",
    "no_spot",
    "ambiguous",
    "too_few_spots",
    "clipped",
    "occluded",
    "wrong_size",
    "unreliable",
    "unreadable",
)


@dataclass(frozen=True)
class PoseEstimate:
    """One frame's answer.

    Attributes
    ----------
    status : str
        One of :data:`STATUSES`.
    tip_in_eye : ndarray, shape (3,), or None
        Estimated tip, mm; ``None`` unless ``status == "ok"``.
    axis : ndarray, shape (3,), or None
        Estimated instrument axis (unit, insertion point toward tip).
    spots : int
        Number of spots used.
    detail : str
        Human-readable reason for a status other than ``ok``, or a remark.
    sigma_mm : float
        1-sigma tip uncertainty per axis (the root of a third of the tip
        covariance's trace), mm (precise method; NaN otherwise).
    rms_px : float
        RMS distance of the edge points from the fitted cones, pixels
        (approximate: the angular residual times the range over the pixel size).
    other_axis : ndarray, shape (3,), or None
        The precise method's cross-check: the axis fitted without the insertion
        point (or with it, when the pose was fitted without).
    roll : float
        Three beams: the fitted roll of beam 0 about the axis from the
        contract's zero roll, radians (0 for one beam and the thesis method).
    """

    status: str
    tip_in_eye: np.ndarray | None = None
    axis: np.ndarray | None = None
    spots: int = 0
    detail: str = ""
    sigma_mm: float = float("nan")
    rms_px: float = float("nan")
    other_axis: np.ndarray | None = None
    roll: float = 0.0

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {STATUSES}, got {self.status!r}")
        if (self.status == "ok") != (self.tip_in_eye is not None and self.axis is not None):
            raise ValueError("a pose is given exactly when status is 'ok'")

    @property
    def ok(self) -> bool:
        """Whether a pose was found."""
        return self.status == "ok"


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


def localize_thesis(image: np.ndarray, setup: Setup) -> PoseEstimate:
    """The thesis's method: Algorithm 1 (one beam) or Algorithm 2 (three beams).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3|4), uint8 or uint16
        Camera frame, RGB(A) or grey.
    setup : Setup
        Only ``eye``, ``camera`` and ``instrument`` are used.
    """
    wrong = check_image_size(image, setup)
    if wrong is not None:
        return wrong
    return locate_from_spots(detect_spots_otsu(image), setup)


def spot_candidates(spot: Spot, setup: Setup, surface: str = "sphere") -> ConeCandidates | None:
    """Both apex candidates of one spot (Algorithm 1 after detection).

    Parameters
    ----------
    spot : Spot
    setup : Setup
        The eye, camera and instrument (with its height correction).
    surface : str
        ``"sphere"``: the retina of ``eye.radius_mm``. ``"plane"``: the plane
        ``z = 0``, the thesis's ellipse test (section 6.2).

    Returns
    -------
    ConeCandidates or None
        ``None`` when the spot is cut by the border or the retina's edge.
    """
    if spot.touches_border:
        return None
    if surface == "plane":
        points = unproject_pixels_to_plane(setup.camera, spot.contour_px)
        normal = np.array([0.0, 0.0, 1.0])
    else:
        points = unproject_pixels_to_sphere(setup.camera, spot.contour_px, setup.eye.radius_mm)
        if not np.all(np.isfinite(points)):
            return None
        normal = sphere_normal(points, setup.eye.center_in_eye)
    return apex_candidates(points, normal, setup.instrument.beam_half_angle, setup.instrument.height_correction)


def _closest_set(candidates: list[ConeCandidates]) -> tuple[int, ...]:
    """One candidate per contour: the combination whose apexes have the smallest summed pairwise distance."""
    best, best_spread = (0,) * len(candidates), np.inf
    for choice in itertools.product((0, 1), repeat=len(candidates)):
        apexes = [c.apexes[i] for c, i in zip(candidates, choice, strict=True)]
        spread = sum(np.linalg.norm(p - q) for p, q in itertools.combinations(apexes, 2))
        if spread < best_spread:
            best, best_spread = choice, spread
    return best


@dataclass(frozen=True)
class _ThesisSolution:
    estimate: PoseEstimate
    spots: tuple[Spot, ...] = ()
    candidates: tuple[ConeCandidates, ...] = ()
    chosen: tuple[int, ...] = ()


def _solve_thesis(detection: SpotDetection, setup: Setup, surface: str) -> _ThesisSolution:
    beams = setup.instrument.beam_count
    spots = detection.spots
    if not spots:
        return _ThesisSolution(
            PoseEstimate(
                "no_spot", detail=f"no region brighter than the background (contrast {detection.contrast:.1f})"
            )
        )
    if len(spots) > beams:
        return _ThesisSolution(
            PoseEstimate("ambiguous", spots=len(spots), detail=f"{len(spots)} spots, expected {beams}")
        )
    pairs = [(spot, c) for spot, c in ((spot, spot_candidates(spot, setup, surface)) for spot in spots) if c]
    needed = 1 if beams == 1 else 2
    if len(pairs) < needed:
        if len(pairs) < len(spots):
            detail = "a spot reaches the image border or the retina's edge"
            return _ThesisSolution(PoseEstimate("clipped", spots=len(spots), detail=detail))
        detail = f"{len(spots)} of {beams} spots, need {needed}"
        return _ThesisSolution(PoseEstimate("too_few_spots", spots=len(spots), detail=detail))
    usable = [c for _, c in pairs]
    if beams == 1:
        chosen: tuple[int, ...] = (choose_by_insertion(usable[0], setup.instrument.insertion_in_eye)[0],)
        tip = usable[0].apexes[chosen[0]]
    else:
        chosen = _closest_set(usable)
        apexes = np.array([c.apexes[i] for c, i in zip(usable, chosen, strict=True)])
        tip = np.median(apexes, axis=0)  # Algorithm 2; the median of two is their mean
    if not setup.contains_point(tip):
        estimate = PoseEstimate("unreliable", spots=len(usable), detail="the fitted apex lies outside the eye")
    else:
        axis = normalize(tip - setup.instrument.insertion_in_eye)  # the thesis's axis
        detail = f"{len(usable)} of {beams} spots" if len(usable) < beams else ""
        estimate = PoseEstimate("ok", tip_in_eye=tip, axis=axis, spots=len(usable), detail=detail)
    return _ThesisSolution(estimate, tuple(s for s, _ in pairs), tuple(usable), chosen)


def locate_from_spots(detection: SpotDetection, setup: Setup, surface: str = "sphere") -> PoseEstimate:
    """The thesis's reconstruction from detected spots (Algorithms 1 and 2).

    One beam: the spot's two apex candidates, the one whose cone axis runs
    along its line from the insertion point. Three beams: two candidates per
    spot, the combination (one per spot) with the smallest spread, and its
    coordinate-wise median; two visible spots still give a pose (their mean),
    with ``spots = 2``. The instrument's axis comes from the insertion point.
    ``instrument.height_correction`` (section 5.5) scales every triangle.
    ``surface`` is that of :func:`spot_candidates`.
    """
    return _solve_thesis(detection, setup, surface).estimate


def edge_half_angle(setup: Setup) -> float:
    """The precise method's edge model, radians: ``instrument.edge_half_angle_deg`` or its default.

    The default is the half-light angle of a Cycles spot of the nominal half-angle
    with Blender's default blend 0.15 (:func:`spotnav.geometry.edge_angle_of_blend`).
    """
    instrument = setup.instrument
    if instrument.edge_half_angle_deg is not None:
        return float(np.radians(instrument.edge_half_angle_deg))
    return edge_angle_of_blend(instrument.beam_half_angle, DEFAULT_BLEND)


def edge_model_options(setup: Setup) -> dict[str, float]:
    """The edge model's keywords for :func:`spotnav.reconstruct.fit_cones`: its uncertainties and the light's radius."""
    return {
        "edge_sigma": EDGE_MODEL_SIGMA,
        "contour_sigma": EDGE_CONTOUR_SIGMA,
        "light_radius": setup.instrument.light_radius_mm,
    }


def _beam_assignment(solution: _ThesisSolution, axis: np.ndarray, setup: Setup) -> tuple[list[int], float] | None:
    """Which beam made each spot, and the starting roll, from the candidates' cone axes (None if unclear)."""
    if setup.instrument.beam_count == 1:
        return [0], 0.0
    cone_axes = np.array([c.cone_axes[i] for c, i in zip(solution.candidates, solution.chosen, strict=True)])
    return assign_beams(cone_axes, axis)


def smallest_spot_area_px(setup: Setup) -> float:
    """Area of the smallest spot a beam makes with the tip ``_MIN_TIP_HEIGHT_MM`` above the retina, pixels.

    A bright region this large may be a spot: it is never dismissed as clutter.
    """
    camera = setup.camera
    radius_px = _MIN_TIP_HEIGHT_MM * np.tan(setup.instrument.beam_half_angle) * camera.focal_px / camera.distance_mm
    return float(np.pi * radius_px**2)


def localize_precise(image: np.ndarray, setup: Setup, *, through_insertion: bool = True) -> PoseEstimate:
    """spotnav's precise method (see :func:`localize_precise_with_edges`)."""
    return localize_precise_with_edges(image, setup, through_insertion=through_insertion)[0]


def localize_precise_with_edges(
    image: np.ndarray, setup: Setup, *, through_insertion: bool = True
) -> tuple[PoseEstimate, EdgeFrame | None]:
    """spotnav's precise method: sub-pixel edges and a direct fit of the cones on the sphere.

    The thesis's closed form (:func:`locate_from_spots`) gives the spots, which
    beam made each and a starting pose. Each spot's edge is then located to a
    fraction of a pixel (:func:`spotnav.detect.detect_edge_subpixel`) and
    back-projected onto the retina, and one instrument pose is fitted to all
    edge points by robust least squares on their angle from the cones of
    half-angle :func:`edge_half_angle` (:func:`spotnav.reconstruct.fit_cones`).
    The estimate carries its 1-sigma tip uncertainty, the RMS residual in
    pixels and the axis fitted without the insertion point (a cross-check).
    A fit that fails its checks gets status ``unreliable``.

    The coarse detection accepts fainter spots than the thesis's; more bright
    regions than beams are ``ambiguous`` unless the extra ones are less than a
    quarter of the size of the smallest spot kept and smaller than any spot
    can be (:func:`smallest_spot_area_px`): clutter such as glints.

    Parameters
    ----------
    image : ndarray
        Camera frame, sRGB-encoded, 8 or 16 bits.
    setup : Setup
        Only ``eye``, ``camera`` and ``instrument`` are used.
    through_insertion : bool
        Constrain the axis through the insertion point (3 unknowns for one
        beam, 4 with the roll for three); ``False`` fits the axis too.

    Returns
    -------
    estimate : PoseEstimate
    edges : EdgeFrame or None
        What the fit started from (for joint fits over frames); None when the
        frame gave no edges to fit.
    """
    wrong = check_image_size(image, setup)
    if wrong is not None:
        return wrong, None
    detection = detect_spots_otsu(image, min_contrast_sigma=_PRECISE_CONTRAST_SIGMA)
    beams = setup.instrument.beam_count
    spots = detection.spots
    if len(spots) > beams:
        extra = spots[beams].area_px
        if extra > _MAX_CLUTTER_AREA * spots[beams - 1].area_px or extra >= smallest_spot_area_px(setup):
            return PoseEstimate("ambiguous", spots=len(spots), detail=f"{len(spots)} spots, expected {beams}"), None
        detection = replace(detection, spots=spots[:beams])
    prepared = _prepare_edges(image, detection, setup, through_insertion)
    if isinstance(prepared, PoseEstimate):
        return prepared, None
    estimate = _fit_precise(prepared, setup, through_insertion)
    if estimate.ok and len(spots) > beams:
        ignored = f"{len(spots) - beams} much smaller bright regions ignored"
        estimate = replace(estimate, detail="; ".join(filter(None, [estimate.detail, ignored])))
    return estimate, prepared


@dataclass(frozen=True)
class EdgeFrame:
    """One frame's material for the precise fit: sub-pixel edges per spot, the beam of each, a start.

    Attributes
    ----------
    edges_px : tuple of ndarray, shape (N_k, 2)
        Each spot's sub-pixel edge points, in order around the spot.
    beams : list of int
        The beam that made each spot.
    start : PoseEstimate
        The thesis's closed form (``ok``).
    axis : ndarray, shape (3,)
        Starting instrument axis.
    roll : float
        Starting roll, radians.
    solution : _ThesisSolution
        The thesis's reconstruction it started from (internal).
    """

    edges_px: tuple[np.ndarray, ...]
    beams: list[int]
    start: PoseEstimate
    axis: np.ndarray
    roll: float
    solution: _ThesisSolution


def _prepare_edges(
    image: np.ndarray, detection: SpotDetection, setup: Setup, through_insertion: bool
) -> EdgeFrame | PoseEstimate:
    """The precise method up to its fit: spots, beams, starting pose and sub-pixel edges.

    Returns the reason (a :class:`PoseEstimate` that is not ``ok``) when the frame cannot be used.
    """
    plain = replace(setup, instrument=replace(setup.instrument, height_correction=1.0))
    # Start from the spots' convex outlines: the shaft or a vessel in front of a spot carves into it.
    detection = replace(detection, spots=tuple(outer_boundary(spot) for spot in detection.spots))
    solution = _solve_thesis(detection, plain, "sphere")
    start = solution.estimate
    if not start.ok:
        return start
    assert start.tip_in_eye is not None and start.axis is not None
    axis = start.axis
    if not through_insertion and len(solution.candidates) == 3:
        # Three symmetric beam axes sum along the instrument's axis, wherever the insertion point is.
        axis = normalize(sum(c.cone_axes[i] for c, i in zip(solution.candidates, solution.chosen, strict=True)))
    assignment = _beam_assignment(solution, axis, setup)
    if assignment is None:
        return PoseEstimate("ambiguous", spots=start.spots, detail="cannot tell which spot each beam made")
    beams, roll = assignment
    spot_edges = [detect_edge_subpixel(image, spot) for spot in solution.spots]
    radii_px = [np.sqrt(spot.area_px / np.pi) for spot in solution.spots]
    problems = [p for p in (edge_problem(e, setup, r) for e, r in zip(spot_edges, radii_px, strict=True)) if p]
    if problems:
        return PoseEstimate("unreliable", spots=start.spots, detail=problems[0])
    return EdgeFrame(tuple(e.pixels for e in spot_edges), beams, start, axis, roll, solution)


def edge_problem(edge: SpotEdge, setup: Setup, radius_px: float) -> str | None:
    """Why a spot's edge cannot be trusted, or None.

    Too few points; noise that biases the halfway level (contrast under
    ``_MIN_CONTRAST_TO_NOISE`` times the noise); a plateau clipped at full
    scale in every channel (over ``_MAX_CLIPPED_FRACTION`` of it), which lowers
    that level and moves the edge outward; or an edge wider than the beam's
    soft band (``2 (beta - edge angle)`` of the spot's radius ``radius_px``)
    plus ``_EDGE_WIDTH_SLACK_PX``: motion blur or defocus, which the edge
    model does not know.
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
    band_px = max(2.0 * (beta - edge_half_angle(setup)) / beta, 0.0) * radius_px
    if edge.width_px > band_px + _EDGE_WIDTH_SLACK_PX:
        return f"the edge is {edge.width_px:.1f} px wide, the beam's {band_px:.1f} px: blurred"
    return None


def hidden_by_shaft(
    setup: Setup,
    edges_px: Sequence[np.ndarray],
    tip_in_eye: np.ndarray,
    axis: np.ndarray,
    margin_mm: float = 0.05,
) -> list[np.ndarray]:
    """Which edge points the instrument's shaft hides from the camera, for a pose.

    The shaft (``instrument.shaft_diameter_mm``) runs from the tip back along
    the axis as far as the insertion point; points within ``margin_mm`` of
    its outline count as hidden too (the edge detector's rays that graze the
    shaft, and the pose's own error).

    Parameters
    ----------
    edges_px : sequence of ndarray, shape (N_k, 2)
        Each spot's edge points, pixels.
    tip_in_eye, axis : ndarray, shape (3,)
    margin_mm : float

    Returns
    -------
    list of ndarray of bool, shape (N_k,)
    """
    instrument = setup.instrument
    if instrument.shaft_diameter_mm == 0:
        return [np.zeros(len(edge), dtype=bool) for edge in edges_px]
    end = tip_in_eye - axis * float(np.linalg.norm(instrument.insertion_in_eye - tip_in_eye))
    radius = instrument.shaft_diameter_mm / 2.0 + margin_mm
    return [pixels_behind_segment(setup.camera, edge, tip_in_eye, end, radius) for edge in edges_px]


def visible_edge_points(
    setup: Setup, edges_px: Sequence[np.ndarray], hidden: Sequence[np.ndarray]
) -> list[np.ndarray] | PoseEstimate:
    """Each spot's edge points on the sphere (mm) without the hidden ones, or ``occluded`` if too few are left."""
    points = []
    for edge, covered in zip(edges_px, hidden, strict=True):
        if covered.mean() > _MAX_HIDDEN_FRACTION or np.sum(~covered) < MIN_EDGE_POINTS:
            detail = f"the shaft hides {100 * covered.mean():.0f} % of a spot's edge"
            return PoseEstimate("occluded", spots=len(edges_px), detail=detail)
        on_sphere = unproject_pixels_to_sphere(setup.camera, edge[~covered], setup.eye.radius_mm)
        points.append(on_sphere[np.all(np.isfinite(on_sphere), axis=1)])
    return points


def _fit_unhidden(
    prepared: EdgeFrame, setup: Setup, edge_angle: float, common: dict, margin_mm: float
) -> tuple[ConeFit, list[np.ndarray]] | PoseEstimate:
    """The fit through the insertion point to the edge the shaft leaves visible, and that edge (mm).

    Which points the shaft hides depends on the pose: they are found again at
    each fitted pose until they stop changing (at most ``_SHAFT_PASSES``
    fits; the first fit uses every point if the start's shaft would hide too
    many). ``occluded`` when the shaft hides too much of a spot's edge at a
    fitted pose.
    """
    start = prepared.start
    assert start.tip_in_eye is not None and start.axis is not None
    hidden = hidden_by_shaft(setup, prepared.edges_px, start.tip_in_eye, start.axis, margin_mm)
    points = visible_edge_points(setup, prepared.edges_px, hidden)
    if isinstance(points, PoseEstimate):  # judge the shaft at a fitted pose instead
        hidden = [np.zeros(len(edge), dtype=bool) for edge in prepared.edges_px]
        points = visible_edge_points(setup, prepared.edges_px, hidden)
    for _ in range(_SHAFT_PASSES):
        if isinstance(points, PoseEstimate):
            return points
        used = points
        fit = fit_cones(used, prepared.beams, edge_angle, insertion_in_eye=setup.instrument.insertion_in_eye, **common)
        now_hidden = hidden_by_shaft(setup, prepared.edges_px, fit.tip_in_eye, fit.axis, margin_mm)
        if all(np.array_equal(a, b) for a, b in zip(hidden, now_hidden, strict=True)):
            break
        hidden = now_hidden
        points = visible_edge_points(setup, prepared.edges_px, hidden)
        common = common | {"tip_in_eye": fit.tip_in_eye, "axis": fit.axis, "roll": fit.roll}
    return fit, used


def _fit_precise(prepared: EdgeFrame, setup: Setup, through_insertion: bool) -> PoseEstimate:
    start, solution, beams, roll, axis = prepared.start, prepared.solution, prepared.beams, prepared.roll, prepared.axis
    assert start.tip_in_eye is not None and start.axis is not None
    instrument = setup.instrument
    common = {
        "beam_count": instrument.beam_count,
        "tilt": instrument.beam_tilt,
        "tip_in_eye": start.tip_in_eye,
        "axis": start.axis,
        "roll": roll,
        **edge_model_options(setup),
    }
    edge_angle = edge_half_angle(setup)
    # Leave out the edge the shaft hides; if the fit fails its checks, leave out a wider band around it.
    for margin_mm in _SHAFT_MARGINS_MM:
        unhidden = _fit_unhidden(prepared, setup, edge_angle, common, margin_mm)
        if isinstance(unhidden, PoseEstimate):
            return unhidden
        constrained, points = unhidden
        if judge_fit(constrained, np.concatenate(points), setup, spots=start.spots).ok:
            break
    # The cross-check continues from the constrained fit. A free pose also tries both thesis
    # candidates for one beam (a cone and its mirror image fit one contour almost equally).
    common.update(tip_in_eye=constrained.tip_in_eye, axis=constrained.axis, roll=constrained.roll)
    free = fit_cones(points, beams, edge_angle, **common)
    if through_insertion:
        return judge_fit(
            constrained, np.concatenate(points), setup, spots=start.spots, detail=start.detail, other_axis=free.axis
        )
    # The shaft runs along the free axis (which the constrained fit does not know, off the insertion line).
    hidden = hidden_by_shaft(setup, prepared.edges_px, free.tip_in_eye, free.axis)
    points = visible_edge_points(setup, prepared.edges_px, hidden)
    if isinstance(points, PoseEstimate):
        return points
    common.update(tip_in_eye=free.tip_in_eye, axis=free.axis, roll=free.roll)
    fits = [fit_cones(points, beams, edge_angle, **common)]
    if instrument.beam_count == 1:
        starts = list(zip(solution.candidates[0].apexes, solution.candidates[0].cone_axes, strict=True))
    else:
        starts = [(start.tip_in_eye, axis)]
        common.update(roll=roll)
    for start_tip, start_axis in starts:
        common.update(tip_in_eye=start_tip, axis=start_axis)
        fits.append(fit_cones(points, beams, edge_angle, **common))
    inside = sorted(
        (f for f in fits if setup.contains_point(f.tip_in_eye)), key=lambda f: float(np.mean(np.abs(f.residuals)))
    )
    if not inside:
        return PoseEstimate("unreliable", spots=start.spots, detail="every fitted tip lies outside the eye")
    best = inside[0]
    for other in inside[1:]:
        close_fit = np.mean(np.abs(other.residuals)) < _MIRROR_RESIDUAL_RATIO * np.mean(np.abs(best.residuals))
        if close_fit and np.linalg.norm(other.tip_in_eye - best.tip_in_eye) > _MIRROR_DISTANCE_MM:
            detail = "a cone and its mirror image fit alike: fix the axis by the insertion point (method precise)"
            return PoseEstimate("ambiguous", spots=start.spots, detail=detail)
    return judge_fit(
        best, np.concatenate(points), setup, spots=start.spots, detail=start.detail, other_axis=constrained.axis
    )


def judge_fit(
    fit: ConeFit,
    points_in_eye: np.ndarray,
    setup: Setup,
    *,
    spots: int,
    detail: str = "",
    other_axis: np.ndarray | None = None,
) -> PoseEstimate:
    """A cone fit as an estimate, or ``unreliable`` when it fails a consistency check.

    Parameters
    ----------
    fit : ConeFit
    points_in_eye : ndarray, shape (N, 3)
        The edge points the fit used, all of them, in the fit's order, mm.
    setup : Setup
    spots : int
        Spots used, for the estimate.
    detail : str
        A remark to carry on an ``ok`` estimate.
    other_axis : ndarray, shape (3,), optional
        The cross-check axis.
    """
    points = points_in_eye
    camera = setup.camera
    distance = np.linalg.norm(points - fit.tip_in_eye, axis=1)
    residual_px = fit.residuals * distance * camera.focal_px / (camera.distance_mm - points[:, 2])
    rms_px = float(np.sqrt(np.mean(residual_px[fit.inliers] ** 2)))
    rms_deg = float(np.degrees(np.sqrt(np.mean(fit.residuals[fit.inliers] ** 2))))
    sigma = fit.tip_sigma_mm
    problems = []
    if fit.inliers.mean() < _MIN_INLIER_FRACTION:
        problems.append(f"only {100 * fit.inliers.mean():.0f} % of the edge fits the cones")
    if rms_deg > _MAX_RMS_DEG and rms_px > _MAX_RMS_PX:
        problems.append(f"RMS residual {rms_deg:.3f} deg ({rms_px:.2f} px)")
    if sigma > _MAX_SIGMA_MM:
        problems.append(f"tip uncertainty {sigma:.3f} mm")
    if not setup.contains_point(fit.tip_in_eye):
        problems.append("the fitted tip lies outside the eye")
    common = {"spots": spots, "sigma_mm": sigma, "rms_px": rms_px}
    if problems:
        return PoseEstimate("unreliable", detail="; ".join(problems), **common)
    return PoseEstimate(
        "ok", tip_in_eye=fit.tip_in_eye, axis=fit.axis, roll=fit.roll, other_axis=other_axis, detail=detail, **common
    )


def fit_height_correction(image: np.ndarray, setup: Setup, tip_in_eye: np.ndarray) -> float:
    """Section 5.5's factor from one frame with the tip at a known position.

    The known height of the tip above each spot's fitting plane divided by the
    reconstructed height ``s2``, averaged over the visible spots.

    Raises
    ------
    ValueError
        When the frame shows no usable spot.
    """
    wrong = check_image_size(image, setup)
    if wrong is not None:
        raise ValueError(wrong.detail)
    detection = detect_spots_otsu(image)
    if len(detection.spots) > setup.instrument.beam_count:
        raise ValueError(f"the calibration frame shows {len(detection.spots)} spots")
    plain = replace(setup, instrument=replace(setup.instrument, height_correction=1.0))
    fits = [c for c in (spot_candidates(s, plain) for s in detection.spots) if c]
    if not fits:
        raise ValueError("the calibration frame shows no whole spot")
    tip_in_eye = np.asarray(tip_in_eye, dtype=float)
    factors = [float((tip_in_eye - c.plane_origin_in_eye) @ c.plane_normal_in_eye) / c.s2 for c in fits]
    return float(np.mean(factors))


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
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    return METHODS[method](image, setup)
