"""The joint geometry fit of calibration: the geometry that frames at known poses determine, and its covariance.

Every edge point of a frame at a known pose (:mod:`spotnav.pose.known_frame`) is
a measurement of the geometry: it must lie on its beam's edge cone once the
camera has turned it into a point on the retina. All frames' points are fitted
at once (:mod:`spotnav.pose.conefit`) to the geometry's parameters
(:data:`spotnav.setup.uncertainty.GEOMETRY_PARAMETERS`: the edge model, the eye's
radius, the camera's rotation, centre, scale, principal point and distortion,
the insertion point) and each three-beam frame's roll.

:func:`fit_geometry` chooses the model itself. A first fit with every
parameter free, held by priors (the setup's ``[uncertainty]``), reaches the
neighbourhood of the answer; then, in the order of :data:`PRIORITY`, each
parameter joins the fit when the frames determine it (its uncertainty from the
frames alone, with the parameters already chosen, under
:data:`DETERMINED_RATIO` of its prior, and none of those already chosen lost).
The others stay at the setup's values and are named: a camera's tilt and
shift look alike from above, as do its focal length and height. The last fit
gives the parameters' covariance, the unchosen ones' uncertainty included, and
the calibrated setup carries it (``[calibration]``, :func:`finish_calibration`)
so that every pose's ``sigma_mm`` does too. A calibration whose edge points
still miss their cones is refused.

With known axes (``known.csv``'s ``dir_x, dir_y, dir_z``) the insertion point
is where the axes' lines meet (least squares); without, the images determine
it, if they can.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import block_diag
from scipy.optimize import minimize_scalar
from scipy.stats import chi2

from spotnav.errors import InputError
from spotnav.optics.camera import unproject_pixels_to_sphere
from spotnav.pose.checks import MAX_RMS_DEG, MAX_RMS_PX, residuals_px
from spotnav.pose.conefit.parameters import (
    EDGE_CONTOUR_SIGMA,
    PARAMETER_GROUPS,
    SHARED_SIZE,
    geometry_covariance,
    geometry_to_file_units,
    geometry_values,
    group_of,
    setup_with_geometry,
)
from spotnav.pose.conefit.problem import ConeProblem, EdgePoints, cone_problem
from spotnav.pose.conefit.solution import ConeSolution
from spotnav.pose.conefit.solvers import fit_cones
from spotnav.pose.determined import (
    DETERMINED_RATIO,
    PRIORITY,
    UNCERTAINTY_KEYS,
    Pinning,
    choose,
    left_reason,
    refusal,
    worse_than_stated,
)
from spotnav.pose.estimate import within_sigmas
from spotnav.pose.known_frame import KnownFrame, KnownFrameEdges, read_known_frame
from spotnav.pose.pipeline import pose_problem
from spotnav.setup.config import Setup
from spotnav.setup.geometry import normalize
from spotnav.setup.uncertainty import GEOMETRY_PARAMETERS, CalibrationRecord, Uncertainty

__all__ = [
    "DETERMINED_RATIO",
    "HELD_OUT_COVERAGE",
    "HELD_OUT_MAX_SIGMAS",
    "MIN_FRAMES",
    "MIN_INLIER_FRACTION",
    "PRIORITY",
    "Calibration",
    "GeometryFit",
    "HeldOut",
    "finish_calibration",
    "fit_geometry",
    "insertion_from_axes",
    "refit",
]

MIN_FRAMES = 3
_MAX_AXES_CONDITION = 1e6  # the known axes' lines must cross at an angle (1e6: some 0.1 deg apart)
MIN_INLIER_FRACTION = 0.5  # a calibration (and a reading chosen by its spots) keeps at least this share of its points
_MAX_COVARIANCE_SCALE = 10.0  # a calibration whose own frames need more is refused
# A calibration misses its held-out frames when one is further than this many 3-D sigmas from its known tip, or
# fewer than this share are within 3 (an honest sigma covers 97 %: two of three leaves room for few frames).
HELD_OUT_MAX_SIGMAS = 5.0
HELD_OUT_COVERAGE = 2.0 / 3.0


@dataclass(frozen=True)
class Calibration:
    """A calibrated geometry: the setup, what was fitted, how well, and the residuals before and after.

    Attributes
    ----------
    setup : Setup
        The calibrated setup, with ``[calibration]``: the geometry's covariance.
    values : ndarray, shape (SHARED_SIZE,)
        Each parameter of :data:`~spotnav.setup.uncertainty.GEOMETRY_PARAMETERS` in the
        calibrated setup, in its units (changes for the camera's rotation and
        focal length).
    sigmas : ndarray, shape (SHARED_SIZE,)
        Their 1-sigma uncertainty after the calibration.
    fitted : tuple of str
        The parameters fitted (names of :data:`~spotnav.setup.uncertainty.GEOMETRY_PARAMETERS`).
    fixed : tuple of (str, str)
        Parameters left at the setup's value, and why.
    insertion_rms_mm : float
        RMS distance of the known axes' lines from the insertion point they
        give (NaN without known axes).
    rms_before_deg, rms_after_deg : float
        RMS angle of the inlying edge points from their cones with the setup's
        geometry and with the calibrated one.
    rms_after_px : float
        The latter in pixels.
    frames : int
        Frames used.
    points : int
        Edge points used (inliers).
    skipped : tuple of str
        Frames left out, with the reason.
    responses : tuple of (str or float, float)
        When the setup stated no response: each candidate tried and the RMS
        of its spots' mean offsets from their cones after its calibration,
        pixels (NaN: its calibration failed); empty otherwise.
    covariance_scale : float
        The factor on the geometry's sigmas (already in ``setup`` and
        ``sigmas``) that its frames' own tips needed (see ``tip_misses_mm``); 1:
        none, or fewer than two frames to tell.
    tip_misses_mm : tuple of float
        How far each frame's tip, found from its edges alone in the calibrated
        setup, is from the known one, mm (the frames whose fit settled).
    edge_bands : tuple of (float, float)
        Where some known frame's spot clips: each soft band tried
        (``instrument.edge_band_deg``, the setup's first) and the RMS of its
        spots' mean offsets from their cones after its calibration, pixels
        (NaN: its calibration failed); empty where none clips.
    held_out : HeldOut or None
        The known frames localized by calibrations without them
        (cross-validation, :func:`spotnav.app.calibrate.check_held_out`); None: not checked.
    apertures : tuple of (float, float)
        Where some known frame's spot clips and the setup states no lens aperture: each ``camera.aperture_mm``
        tried (a pinhole's first) and its spots' RMS offset, pixels (NaN: its calibration failed); empty otherwise.
        The one fitted is the calibrated setup's, its 1 sigma ``calibration.aperture_sigma_mm``.
    """

    setup: Setup
    values: np.ndarray
    sigmas: np.ndarray
    fitted: tuple[str, ...]
    fixed: tuple[tuple[str, str], ...]
    insertion_rms_mm: float
    rms_before_deg: float
    rms_after_deg: float
    rms_after_px: float
    frames: int
    points: int
    skipped: tuple[str, ...] = ()
    responses: tuple[tuple[str | float, float], ...] = ()
    covariance_scale: float = 1.0
    tip_misses_mm: tuple[float, ...] = ()
    edge_bands: tuple[tuple[float, float], ...] = ()
    apertures: tuple[tuple[float, float], ...] = ()
    held_out: HeldOut | None = None


@dataclass(frozen=True)
class HeldOut:
    """A calibration's held-out check: each known frame localized (the precise method) with a calibration of the
    other frames (``folds``-fold cross-validation), against its known tip.

    Attributes
    ----------
    folds : int
        How many calibrations: each leaves every ``folds``-th frame out.
    names : tuple of str
        The frames checked.
    statuses : tuple of str
        Each one's status (``ok``, or why it was not answered; ``refused`` when
        the calibration without it was refused).
    errors_mm : tuple of float
        Each answered tip's 3-D distance from the known one, mm (NaN: not answered).
    sigma_mm : tuple of float
        Each answer's ``sigma_mm`` (NaN: not answered).
    """

    folds: int
    names: tuple[str, ...]
    statuses: tuple[str, ...]
    errors_mm: tuple[float, ...]
    sigma_mm: tuple[float, ...]

    @property
    def answered(self) -> int:
        """Frames answered ``ok``."""
        return sum(status == "ok" for status in self.statuses)

    def sigmas(self) -> np.ndarray:
        """Each answered frame's error in 3-D standard errors (``sqrt(3) sigma_mm``, as
        :func:`~spotnav.pose.estimate.within_sigmas` counts them), shape (answered,)."""
        errors, sigma = self._answered()
        return np.asarray(errors / (np.sqrt(3.0) * sigma))

    def coverage(self) -> float:
        """The answered frames' share within 3 sigma (3-D); NaN when none was answered."""
        errors, sigma = self._answered()
        return float(np.mean(within_sigmas(errors, sigma))) if len(errors) else float("nan")

    def misses(self) -> bool:
        """Whether the calibration misses its held-out frames: under half answered, one over
        :data:`HELD_OUT_MAX_SIGMAS`, or under :data:`HELD_OUT_COVERAGE` within 3 sigma."""
        if 2 * self.answered < len(self.statuses):
            return True
        return bool(np.any(self.sigmas() > HELD_OUT_MAX_SIGMAS) or self.coverage() < HELD_OUT_COVERAGE)

    def _answered(self) -> tuple[np.ndarray, np.ndarray]:
        ok = np.array([status == "ok" for status in self.statuses], dtype=bool)
        return np.array(self.errors_mm)[ok], np.array(self.sigma_mm)[ok]


@dataclass(frozen=True)
class GeometryFit:
    """One calibration's fit before its frame-edge sigma and check (:func:`fit_geometry`): the setup it started from
    (the response it read with, the insertion point its axes gave), its frames' edges (all ``ok``), the axis mode
    (``known`` or ``insertion``), the parameters fitted (indices of
    :data:`~spotnav.setup.uncertainty.GEOMETRY_PARAMETERS`),
    the last fit, the edge points' RMS angle from their cones with the setup's geometry (radians), why each parameter
    not fitted stayed at the setup's value, where known axes meet (:func:`insertion_from_axes`), the frames left out
    with the reason, and which of the frames given each of ``edges`` is (indices)."""

    setup: Setup
    edges: list[KnownFrameEdges]
    axis_mode: str
    chosen: list[int]
    solution: ConeSolution
    rms_before: float
    reasons: dict[int, str]
    lines: tuple[np.ndarray, np.ndarray, float] | None
    skipped: list[str]
    used: tuple[int, ...] = ()

    def spot_spread_px(self) -> float:
        """RMS of the spots' mean offsets from their cones after the fit, pixels: how well they agree."""
        problem, inliers = self.solution.problem, self.solution.inliers
        residuals = _residuals_px(setup_with_geometry(self.setup, self.solution.shared), self.solution)
        spots = [(problem.points.spot == s) & inliers for s in np.unique(problem.points.spot)]
        offsets = [residuals[spot].mean() for spot in spots if spot.any()]
        return float(np.sqrt(np.mean(np.square(offsets)))) if offsets else float("nan")


def insertion_from_axes(tips_in_eye: np.ndarray, axes: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Where the instrument's lines meet: the point nearest all of them, least squares.

    Parameters
    ----------
    tips_in_eye, axes : ndarray, shape (F, 3)
        A point on each line and its direction.

    Returns
    -------
    point : ndarray, shape (3,), mm
    covariance : ndarray, shape (3, 3), mm^2
        From the lines' scatter about the point (two constraints per line).
    rms_mm : float
        RMS distance of the lines from the point.
    """
    axes = normalize(axes)
    projectors = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    normal = projectors.sum(axis=0)
    if np.linalg.cond(normal) > _MAX_AXES_CONDITION:
        raise InputError("the known axes are (nearly) parallel: they do not fix the insertion point")
    point = np.linalg.solve(normal, np.einsum("fij,fj->i", projectors, tips_in_eye))
    offsets = np.einsum("fij,fj->fi", projectors, point - tips_in_eye)
    squares = float(np.sum(offsets**2))
    variance = squares / max(2 * len(axes) - 3, 1)
    return point, variance * np.linalg.inv(normal), float(np.sqrt(squares / len(axes)))


def _problem(
    setup: Setup, frames: list[KnownFrameEdges], axis: str, free: Sequence[int], shared: np.ndarray
) -> ConeProblem:
    """The frames' edges as one cone problem: the tips known, the rolls free, the shared ``free`` too."""
    points = EdgePoints.of_frames([f.edges_px for f in frames], [f.beams for f in frames])
    return cone_problem(
        setup,
        points,
        np.array([f.tip for f in frames]),
        np.array([f.axis for f in frames]),
        np.array([f.roll for f in frames]),
        axis=axis,
        free_tips=False,
        free_shared=free,
        shared=shared,
        one_frame=False,
    )


def fit_geometry(frames: Sequence[KnownFrame], setup: Setup, fit: Sequence[str], fix: Sequence[str]) -> GeometryFit:
    """The edges read with the setup's response, the parameters the frames determine, and the last fit.

    Raises
    ------
    InputError
        Fewer than :data:`MIN_FRAMES` usable frames; nothing to calibrate; a
        forced group the frames cannot determine (one sentence: why, and what
        frames would); known axes that are (nearly) parallel or with the
        insertion point forced. A geometry out of its allowed ranges raises
        :class:`~spotnav.setup.values.SetupError`.
    """
    edges, skipped, used = [], [], []
    for number, frame in enumerate(frames):
        result = read_known_frame(frame, setup)
        if result.ok:
            edges.append(result)
            used.append(number)
        else:
            skipped.append(f"{result.detail} ({result.status})")
    known_axes = all(frame.axis is not None for frame in frames)
    return replace(_fit_edges(edges, setup, fit, fix, known_axes, skipped), used=tuple(used))


def refit(fitted: GeometryFit, keep: Sequence[int]) -> GeometryFit:
    """``fitted`` again from some of its frames' edges (indices into ``fitted.edges``): a held-out check's fit.

    The same parameters from the same start (the response, soft band and model that all the frames chose); known
    axes give the insertion point anew, from these frames'.
    """
    edges = [fitted.edges[k] for k in keep]
    setup, lines = fitted.setup, None
    if fitted.lines is not None:
        lines = insertion_from_axes(np.array([e.tip for e in edges]), np.array([e.axis for e in edges]))
        setup = replace(setup, instrument=replace(setup.instrument, insertion_point_mm=tuple(lines[0])))
    before = _problem(setup, edges, fitted.axis_mode, [], np.zeros(SHARED_SIZE))
    solution = fit_cones(_problem(setup, edges, fitted.axis_mode, fitted.chosen, fitted.solution.shared))
    rms_before = _rms(before.residuals(before.start), solution.inliers)
    used = tuple(fitted.used[k] for k in keep)
    return replace(fitted, setup=setup, edges=edges, solution=solution, rms_before=rms_before, lines=lines, used=used)


def _fit_edges(
    edges: list[KnownFrameEdges],
    setup: Setup,
    fit: Sequence[str],
    fix: Sequence[str],
    known_axes: bool,
    skipped: list[str],
) -> GeometryFit:
    """:func:`fit_geometry` from the frames' edges read."""
    if len(edges) < MIN_FRAMES:
        left_out = "; ".join(skipped) if skipped else "none given"
        raise InputError(f"calibration needs at least {MIN_FRAMES} usable frames, got {len(edges)} ({left_out})")
    reasons = {i: "fixed (--fix)" for name in fix for i in PARAMETER_GROUPS[name]}
    prior = np.sqrt(np.diag(geometry_covariance(setup, one_frame=False)))
    exact = [name for name in fit if np.any(prior[list(PARAMETER_GROUPS[name])] == 0)]
    if exact:  # --fit overrules [uncertainty] 0: judge what the frames tell against a real microscope's prior
        typical = {UNCERTAINTY_KEYS[name]: getattr(Uncertainty(), UNCERTAINTY_KEYS[name]) for name in exact}
        setup = replace(setup, uncertainty=replace(setup.uncertainty, **typical))
        prior = np.sqrt(np.diag(geometry_covariance(setup, one_frame=False)))
    reasons.update({i: "known exactly ([uncertainty] 0)" for i in range(SHARED_SIZE) if prior[i] == 0})
    if setup.instrument.beam_count == 1:
        reasons.update({i: "one beam has no tilt" for i in PARAMETER_GROUPS["beam-tilt"]})
    lines = None
    if known_axes:
        if "insertion-point" in fit:
            raise InputError("with known axes the insertion point is where they meet; leave --fit insertion-point out")
        if "insertion-point" not in fix:
            lines = insertion_from_axes(np.array([e.tip for e in edges]), np.array([e.axis for e in edges]))
            setup = replace(setup, instrument=replace(setup.instrument, insertion_point_mm=tuple(lines[0])))
        reasons.update({i: reasons.get(i, "where the known axes meet") for i in PARAMETER_GROUPS["insertion-point"]})
    axis_mode = "known" if known_axes else "insertion"
    forced = list(dict.fromkeys(i for name in fit for i in PARAMETER_GROUPS[name]))
    order = [*PRIORITY, *(i for i in range(SHARED_SIZE) if i not in PRIORITY)]
    candidates = [i for i in order if i in forced or (i in PRIORITY and i not in reasons)]
    if not candidates:
        raise InputError(
            "nothing to calibrate: the setup's [uncertainty] says its geometry is known exactly "
            "(leave the section out for a real microscope, or force parameters with --fit)"
        )
    zeros = np.zeros(SHARED_SIZE)
    before = _problem(setup, edges, axis_mode, [], zeros)
    # First every candidate, held by its prior; then the ones the frames determine, on their own.
    everything = _problem(setup, edges, axis_mode, candidates, zeros)
    widths = np.full(everything.size, np.inf)
    widths[: len(candidates)] = np.where(prior[candidates] > 0, prior[candidates], np.inf)
    held = fit_cones(everything, priors=widths)
    ratios = Pinning(held, candidates)
    chosen, tried = choose(ratios, candidates, forced)
    unresolved = [i for i in forced if not tried[i] < DETERMINED_RATIO]
    if unresolved:
        raise InputError(refusal(ratios, setup, unresolved[0], forced, edges))
    reasons.update({i: left_reason(ratios, setup, i, tried[i], chosen) for i in candidates if i not in chosen})
    chosen = sorted(chosen)
    start = np.where(np.isin(np.arange(SHARED_SIZE), chosen), held.shared, 0.0)
    solution = fit_cones(_problem(setup, edges, axis_mode, chosen, start))
    worse = worse_than_stated(ratios, setup, forced, chosen, np.sqrt(np.diag(solution.covariance)[: len(chosen)]))
    if worse:
        raise InputError(worse)
    rms_before = _rms(before.residuals(before.start), solution.inliers)
    return GeometryFit(setup, edges, axis_mode, chosen, solution, rms_before, reasons, lines, skipped)


def finish_calibration(fitted: GeometryFit) -> Calibration:
    """The calibration of a fit: its frame-edge sigma, its check and its covariance, scaled up if its own frames'
    tips, found from their edges alone, miss the known ones by more than it says (:func:`_frame_misses`,
    :func:`_most_likely_scale`); refused when that takes more than ``_MAX_COVARIANCE_SCALE`` times its sigmas."""
    frame_edge = _frame_edge_sigma(fitted.setup, fitted.edges, fitted.axis_mode, fitted.chosen, fitted.solution.shared)
    calibration = _calibration(
        fitted.setup,
        fitted.solution,
        fitted.chosen,
        fitted.rms_before,
        frame_edge,
        fitted.reasons,
        fitted.lines,
        fitted.skipped,
    )
    misses, own, gains, geometry = _frame_misses(calibration.setup, fitted.edges)
    scale = _most_likely_scale(misses, own, gains, geometry) if len(misses) >= 2 else 1.0
    distances = tuple(float(np.linalg.norm(miss)) for miss in misses)
    if scale >= _MAX_COVARIANCE_SCALE:
        raise InputError(
            f"the calibrated geometry does not find its own frames' tips: from their edges alone they land "
            f"{np.mean(distances):.4f} mm from the known ones on average, over {_MAX_COVARIANCE_SCALE:g} times what "
            "its covariance allows; check known.csv (tips in the eye frame, images in its order) and the setup's beam"
        )
    record = calibration.setup.calibration
    covariance = tuple(tuple(scale**2 * v for v in row) for row in record.covariance)
    setup = replace(calibration.setup, calibration=replace(record, covariance=covariance))
    return replace(
        calibration, setup=setup, sigmas=scale * calibration.sigmas, covariance_scale=scale, tip_misses_mm=distances
    )


def _frame_misses(
    calibrated: Setup, edges: list[KnownFrameEdges]
) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Each calibration frame's tip found from its edges alone in ``calibrated``, against the known one.

    The pose is fitted to the frame's calibration edges (one ray per pixel, the points the shaft hides kept, no
    spot's own blur term), the tip free and the axis through the insertion point, from the known pose. The
    calibration fit made the edges agree with the known tips; what it left at the setup's values (several parameters
    wrong at once) still moves a tip found from the edges alone, mostly along the instrument's axis. Frames whose fit
    did not settle (a tip held at its box) are left out.

    Returns
    -------
    misses : list of ndarray, shape (3,)
        Fitted tip minus known tip, mm.
    own : list of ndarray, shape (3, 3)
        Each one's covariance from its own frame: its edge points' and one frame's edge-model error, mm^2.
    gains : list of ndarray, shape (3, G)
        How each tip moves with the geometry's parameters that carry uncertainty (engine units).
    geometry : ndarray, shape (G, G)
        Their covariance, shared by every frame (the calibrated one, without the one-frame edge-model error).
    """
    one_frame, geometry = geometry_covariance(calibrated), geometry_covariance(calibrated, one_frame=False)
    ids = np.flatnonzero(np.diag(one_frame) > 0)
    misses, own, gains = [], [], []
    for frame in edges:
        fit = fit_cones(
            pose_problem(calibrated, frame.edges_px, frame.beams, frame.tip, frame.axis, frame.roll),
            solver="levenberg-marquardt",
        )
        if not fit.settled:
            continue
        if not np.array_equal(fit.geometry_ids, ids):
            raise ValueError(f"the fit carries geometry parameters {fit.geometry_ids}, expected {ids.tolist()}")
        data, gain = fit.tip_terms()
        misses.append(fit.tip() - frame.tip)
        own.append(data + gain @ (one_frame - geometry)[np.ix_(ids, ids)] @ gain.T)
        gains.append(gain)
    return misses, own, gains, geometry[np.ix_(ids, ids)]


def _most_likely_scale(
    misses: Sequence[np.ndarray], own: Sequence[np.ndarray], gains: Sequence[np.ndarray], geometry: np.ndarray
) -> float:
    """The most likely factor ``k`` in [1, ``_MAX_COVARIANCE_SCALE``] on the geometry's sigmas, given frames' misses.

    The misses (F of (3,), stacked (3F,)) are taken as Gaussian with covariance ``B + k^2 G R G^T``: ``B`` block
    diagonal, each frame's ``own`` (3, 3); ``R`` the ``geometry`` (G, G), one error shared by every frame, through
    the ``gains`` (F of (3, G), stacked (3F, G)). Within 0.5 % of 1 is 1; within 0.1 % of the bound, the bound.
    """
    stacked, gain = np.concatenate(misses), np.vstack(gains)
    independent, shared = block_diag(*own), gain @ geometry @ gain.T

    def deviance(log_scale: float) -> float:
        """Minus twice the misses' log-likelihood (less a constant) with the geometry's sigmas scaled by e^log_scale."""
        covariance = independent + np.exp(2.0 * log_scale) * shared
        return float(stacked @ np.linalg.solve(covariance, stacked) + np.linalg.slogdet(covariance)[1])

    best = minimize_scalar(
        deviance, bounds=(0.0, np.log(_MAX_COVARIANCE_SCALE)), method="bounded", options={"xatol": 1e-4}
    )
    scale = float(np.exp(best.x))
    if scale > 0.999 * _MAX_COVARIANCE_SCALE:
        return _MAX_COVARIANCE_SCALE  # the bound itself, or more
    return scale if scale > 1.005 and deviance(best.x) < deviance(0.0) else 1.0


def _frame_edge_sigma(
    setup: Setup, edges: list[KnownFrameEdges], axis_mode: str, chosen: list[int], shared: np.ndarray
) -> float:
    """How far one frame's edge strays from the edge model as a whole, radians: each frame left out in turn.

    The edge model (its angle, and the light's radius if fitted) is fitted to
    the other frames in the calibrated camera and eye; the left-out frame's own
    edge angle (its known pose, the roll free) then differs from it by an
    offset. The offsets' mean square (the upper end of its 68 % interval: a
    few frames tell a spread only roughly), less what each spot's own
    whole-edge shift (:data:`~spotnav.pose.conefit.parameters.EDGE_CONTOUR_SIGMA`, over the
    frame's spots) explains, is the frame's share.
    """
    edge = PARAMETER_GROUPS["edge-angle"][0]
    model = [i for i in chosen if group_of(i) in ("edge-angle", "light-radius")]
    offsets = []
    for f in range(len(edges)):
        others = edges[:f] + edges[f + 1 :]
        geometry = fit_cones(_problem(setup, others, axis_mode, model, shared)).shared
        alone = fit_cones(_problem(setup, edges[f : f + 1], axis_mode, [edge], geometry))
        offsets.append(alone.shared[edge] - geometry[edge])
    # a float for max() (the same np.float64 value; NumPy's stubs give np.mean of a list no float type)
    square = float(np.mean(np.square(offsets)) * len(offsets) / chi2.ppf(0.16, len(offsets)))
    return float(np.sqrt(max(square - EDGE_CONTOUR_SIGMA**2 / setup.instrument.beam_count, 0.0)))


def _rms(residuals: np.ndarray, inliers: np.ndarray) -> float:
    return float(np.sqrt(np.mean(residuals[inliers] ** 2)))


def _residuals_px(calibrated: Setup, solution: ConeSolution) -> np.ndarray:
    """Each edge point's distance from its cone in ``calibrated``'s camera, pixels (N,)."""
    problem = solution.problem
    points = unproject_pixels_to_sphere(calibrated.camera, problem.points.pixels, calibrated.eye.radius_mm)
    return residuals_px(calibrated.camera, points, problem.frames[problem.points.frame, :3], solution.residuals)


def _calibration(
    setup: Setup,
    solution: ConeSolution,
    chosen: list[int],
    rms_before: float,
    frame_edge: float,
    reasons: dict[int, str],
    lines: tuple[np.ndarray, np.ndarray, float] | None,
    skipped: list[str],
) -> Calibration:
    """The calibration from the final fit: its check, its covariance and the calibrated setup."""
    problem, inliers = solution.problem, solution.inliers
    rms_after = _rms(solution.residuals, inliers)
    calibrated = setup_with_geometry(setup, solution.shared)
    rms_px = float(np.sqrt(np.mean(_residuals_px(calibrated, solution)[inliers] ** 2)))
    if inliers.mean() < MIN_INLIER_FRACTION or (np.degrees(rms_after) > MAX_RMS_DEG and rms_px > MAX_RMS_PX):
        raise InputError(
            f"the calibrated model does not fit the frames: RMS {np.degrees(rms_after):.3f} deg ({rms_px:.2f} px) "
            f"after, {np.degrees(rms_before):.3f} deg before, {100 * inliers.mean():.0f} % of the edge points fit; "
            "check known.csv (tips in the eye frame, images in its order) and the setup's beam (count, angles)"
        )
    covariance = _geometry_covariance(solution, None if lines is None else lines[1])
    fitted = [*chosen, *([] if lines is None else PARAMETER_GROUPS["insertion-point"])]
    record = CalibrationRecord(
        parameters=GEOMETRY_PARAMETERS,
        covariance=tuple(tuple(float(v) for v in row) for row in covariance),
        fitted=tuple(GEOMETRY_PARAMETERS[i] for i in sorted(fitted)),
        rms_deg=float(np.degrees(rms_after)),
        frames=len(problem.frames),
        frame_edge_sigma_deg=float(np.degrees(frame_edge)),
    )
    calibrated = replace(calibrated, calibration=record)
    values = geometry_values(calibrated)
    changes_only = [*PARAMETER_GROUPS["camera-rotation"], *PARAMETER_GROUPS["focal-length"]]
    values[changes_only] = geometry_to_file_units(solution.shared)[changes_only]
    return Calibration(
        setup=calibrated,
        values=values,
        sigmas=np.sqrt(np.diag(covariance)),
        fitted=record.fitted,
        fixed=tuple((GEOMETRY_PARAMETERS[i], reasons[i]) for i in range(SHARED_SIZE) if i not in fitted),
        insertion_rms_mm=float("nan") if lines is None else lines[2],
        rms_before_deg=float(np.degrees(rms_before)),
        rms_after_deg=float(np.degrees(rms_after)),
        rms_after_px=rms_px,
        frames=len(problem.frames),
        points=int(inliers.sum()),
        skipped=tuple(skipped),
    )


def _geometry_covariance(solution: ConeSolution, insertion_covariance: np.ndarray | None) -> np.ndarray:
    """The calibrated geometry's error covariance over every shared parameter, file units, (SHARED_SIZE,)*2.

    The fitted ones: the fit's covariance, which carries the fixed ones'
    uncertainty; the fixed ones: their prior ``C``; between them ``-M C``,
    ``M`` the fit's geometry gain (a true value ``d`` away from a fixed one
    moves the fitted ones by ``M d``, while the fixed one's error is ``-d``).
    An insertion point from the known axes' lines brings its own covariance.
    """
    problem = solution.problem
    chosen, fixed = list(problem.free_shared), list(solution.geometry_ids)
    covariance = np.array(problem.prior, dtype=float)
    covariance[chosen, :] = 0.0
    covariance[:, chosen] = 0.0
    covariance[np.ix_(chosen, chosen)] = solution.covariance[: len(chosen), : len(chosen)]
    if fixed and chosen:
        cross = -solution.geometry_gain[: len(chosen)] @ problem.prior[np.ix_(fixed, fixed)]
        covariance[np.ix_(chosen, fixed)] = cross
        covariance[np.ix_(fixed, chosen)] = cross.T
    if insertion_covariance is not None:
        insertion = list(PARAMETER_GROUPS["insertion-point"])
        covariance[insertion, :] = 0.0
        covariance[:, insertion] = 0.0
        covariance[np.ix_(insertion, insertion)] = insertion_covariance
    scale = geometry_to_file_units(np.ones(SHARED_SIZE))
    covariance = covariance * np.outer(scale, scale)
    symmetric: np.ndarray = 0.5 * (covariance + covariance.T)
    return symmetric
