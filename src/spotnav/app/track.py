"""Track a moving instrument frame by frame: the precise method on a region of interest.

The first frame is localized on the whole image
(:func:`spotnav.pose.precise.localize_precise`): *acquisition*. After that the
tracker predicts the pose (the tip's last step, changed as it changed from the
step before when that change agrees with the one before it: a steady turn), projects each beam's predicted
edge curve into the image and reads the image only along rays across it
(:func:`spotnav.image.rays.detect_edge_along_rays`): the rays are the region of
interest, a few per cent of the pixels. The cone fit starts from the
prediction, so the fit keeps the apex that continues the track. A tracked
frame whose fit fails a check, or whose tip jumps further than
``max_jump_mm`` from the prediction, is localized on the whole image again in
the same call. After a loss (the spot hidden, or refused) the next frames are
first read where the spot was last seen, with the same rays and checks
(*re-acquisition*; up to ``_MAX_LOST_FRAMES`` lost frames later), and only
then on the whole image.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from numba import njit

from spotnav.image.rays import curve_rays, detect_edge_along_rays, rays_through_curve
from spotnav.optics.camera import camera_model, project_points, project_rows
from spotnav.optics.edgeblur import frame_blur_for_width, frame_blur_shift, response_curve
from spotnav.optics.light import edge_angle
from spotnav.optics.pixelnoise import advance_noise_pool, discard_noise_reading, new_noise_pool, pooled_frame_blur
from spotnav.pose.checks import check_image_size, judge_edge, judge_fit
from spotnav.pose.conefit.solution import ConeSolution
from spotnav.pose.conefit.solvers import fit_cones
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.pipeline import (
    LightReading,
    RayFan,
    SpotPlan,
    fit_visible,
    fitted_edges_px,
    pose_problem,
    read_light,
    refit_free_axis,
)
from spotnav.pose.precise import localize_precise, localize_precise_with_edges
from spotnav.pose.reconstruct import fit_ellipse
from spotnav.pose.sequence import AxesMeeting, axis_line
from spotnav.pose.shaft import hidden_by_shaft
from spotnav.setup.config import Setup
from spotnav.setup.geometry import beam_axes, cone_sphere_curve, cone_sphere_points, normalize
from spotnav.setup.sections import check_localized_beams

__all__ = ["TRACK_MODES", "TrackedFrame", "Tracker", "frozen_heap", "prepare_kernels", "track_frame"]

TRACK_MODES = ("tracked", "reacquired", "acquired", "lost")
_CURVE_POINTS = 90
_BORDER_PX = 2.0
_MAX_LOST_FRAMES = 10  # after this many frames without a pose the last one seen is too old to search from
_REHEARSAL_RAYS = 64  # the fewest: a rehearsal is over soon after a frame arrives
# The sequence's test hears every answered frame's axis at first, then one in so many (a free fit costs a quarter
# of a tracked frame: 2048 px, one beam, 1.32 ms a frame against 1.00).
_LISTEN_FRAMES = 100
_LISTEN_EVERY = 10
# The frames it hears: those answered, and those whose three beams showed an axis off the insertion line (their
# fit is sound; it is the setup they contradict, which is what the test weighs).
_HEARD = ("ok", "miscalibrated")
_MIN_EDGE_RAY_FRACTION = 0.5  # fewer rays with an edge: the spot is not where it was predicted
# A fit further than this from the prediction read its rays aslant (on the Cycles helix, 0.6 mm a frame, a
# 0.2 mm miss biased the tip by 0.01 mm): its edges are read again from the fitted pose.
_REREAD_MM = 0.03
# What _predicted_rays found: rays on the image, or why a beam's predicted spot cannot be read (as an estimate).
_ON_IMAGE, _OUTSIDE_EYE, _OFF_RETINA, _AT_BORDER = 0, 1, 2, 3
_REFUSALS = {
    _OUTSIDE_EYE: ("unreliable", "the predicted tip lies outside the eye"),
    _OFF_RETINA: ("clipped", "a predicted spot leaves the retina"),
    _AT_BORDER: ("clipped", "a predicted spot reaches the image's border"),
}


@dataclass(frozen=True)
class TrackedFrame:
    """One frame's answer from :class:`Tracker`.

    Attributes
    ----------
    estimate : PoseEstimate
        The pose, or why there is none.
    mode : str
        ``tracked`` (region of interest), ``reacquired`` (after a loss, where
        the spot was last seen), ``acquired`` (whole image) or ``lost`` (no
        pose; the next frame tries where it was last seen, then the whole
        image).
    edges_px : tuple of ndarray, shape (N_k, 2)
        The edge points the frame's fit used, per beam, pixels (for an
        overlay); empty when no fit ran.
    """

    estimate: PoseEstimate
    mode: str
    edges_px: tuple[np.ndarray, ...] = ()


def track_frame(
    image: np.ndarray,
    setup: Setup,
    predicted: PoseEstimate,
    *,
    through_insertion: bool = True,
    max_rays: int = 128,
) -> PoseEstimate:
    """Localize the tip near a predicted pose, reading the image only around the predicted edges.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) or (H, W)
        The frame, sRGB-encoded, the camera's size.
    setup : Setup
    predicted : PoseEstimate
        An ``ok`` estimate near the frame's pose (tip, axis and roll are used).
    through_insertion : bool
        Constrain the axis through the insertion point (as method ``precise``).
    max_rays : int
        Most rays per spot (one per two pixels of the predicted edge, at least
        64). More rays hardly help: the error left is each spot's whole-edge
        shift, which no number of rays averages away (at 5000 px, 256 rays
        track a helix as well as 1024; at 2048 px, 150 helix frames, 128 rays
        0.0021 / 0.0170 mm mean / max against 256's 0.0021 / 0.0152, in 1.56
        ms a frame against 1.95).

    Returns
    -------
    PoseEstimate
        ``ok``, or ``clipped`` (a predicted edge leaves the image), or
        ``unreliable`` (an edge on fewer than half the rays: the spot is not
        where predicted; or a check of :func:`spotnav.pose.checks.judge_fit`
        failed), or ``occluded`` (the shaft, at the predicted pose, hides too
        much of a spot's edge; its hidden edge points are never used).

    Raises
    ------
    SetupError
        For 2 or 4 beams (simulation only, :func:`~spotnav.setup.sections.check_localized_beams`).
    """
    check_localized_beams(setup.instrument)
    return _track_with_edges(image, setup, predicted, through_insertion, max_rays)[0]


def _track_with_edges(
    image: np.ndarray,
    setup: Setup,
    predicted: PoseEstimate,
    through_insertion: bool,
    max_rays: int,
    noise_pools: Sequence[np.ndarray] | None = None,
) -> tuple[PoseEstimate, tuple[np.ndarray, ...], ConeSolution | None]:
    """:func:`track_frame`, the edge points its fit used (empty when none ran) and the fit (None when none ran);
    with the stream's ``noise_pools`` (:func:`spotnav.pose.pipeline.read_light`)."""
    wrong = check_image_size(image, setup)
    if wrong is not None:
        return wrong, (), None
    estimate, edges, fit = _track_once(image, setup, predicted, through_insertion, max_rays, noise_pools)
    if fit is not None and _worth_reading(estimate, fit, predicted, setup):
        # The rays crossed the edge aslant, from a centre that was off: read them again across the fitted edge.
        fitted = PoseEstimate("ok", tip_in_eye=fit.tip(), axis=fit.axis(), roll=fit.roll())
        estimate, edges, fit = _track_once(image, setup, fitted, through_insertion, max_rays, noise_pools)
    return estimate, edges, fit


def _flagged(estimate: PoseEstimate, verdict: str) -> PoseEstimate:
    """An ``ok`` estimate withheld as ``mismatch``: the sequence's test says the setup biases it."""
    return replace(estimate, status="mismatch", tip_in_eye=None, axis=None, other_axis=None, detail=verdict)


def _worth_reading(estimate: PoseEstimate, fit: ConeSolution, predicted: PoseEstimate, setup: Setup) -> bool:
    """Whether the rays are worth reading again from a fit's pose: one more than ``_REREAD_MM`` from the
    prediction, accepted, or refused by its own checks or its residuals' test (rays aslant across vessels misread
    its residuals) with its tip settled inside the eye; not one the geometry's uncertainty refused, which no
    reading changes."""
    if np.linalg.norm(fit.tip() - predicted.pose()[0]) <= _REREAD_MM:
        return False
    if estimate.ok:
        return True
    return estimate.status in ("unreliable", "mismatch") and fit.settled and setup.contains_point(fit.tip())


def _track_once(
    image: np.ndarray,
    setup: Setup,
    predicted: PoseEstimate,
    through_insertion: bool,
    max_rays: int,
    noise_pools: Sequence[np.ndarray] | None,
) -> tuple[PoseEstimate, tuple[np.ndarray, ...], ConeSolution | None]:
    """One pass of :func:`track_frame`: the edges along rays across the predicted edge curves, and the fit (None
    when none ran)."""
    read = _read_predicted_edges(image, setup, predicted, max_rays, noise_pools)
    if isinstance(read, PoseEstimate):
        return read, (), None
    return _fit_read_edges(setup, predicted, read, through_insertion)


def _read_predicted_edges(
    image: np.ndarray,
    setup: Setup,
    predicted: PoseEstimate,
    max_rays: int,
    noise_pools: Sequence[np.ndarray] | None = None,
) -> LightReading | PoseEstimate:
    """The find stage from a prediction (:func:`_plan_predicted`), then each beam's light read where it was
    predicted; or why it cannot be read or used."""
    plan = _plan_predicted(setup, predicted, max_rays)
    if isinstance(plan, PoseEstimate):
        return plan
    return read_light(image, setup, plan, min_edge_fraction=_MIN_EDGE_RAY_FRACTION, noise_pools=noise_pools)


def _plan_predicted(setup: Setup, predicted: PoseEstimate, max_rays: int) -> SpotPlan | PoseEstimate:
    """Tracking's find stage: rays across each beam's predicted edge curve, one spot per beam, or why a predicted
    spot cannot be read (``clipped``, ``unreliable``)."""
    predicted_tip, predicted_axis = predicted.pose()
    camera, instrument = setup.camera, setup.instrument
    angle = edge_angle(setup)
    axes = beam_axes(predicted_axis, instrument.beam_count, instrument.beam_tilt, predicted.roll)
    fans = []
    model, eye = camera_model(camera), setup.eye
    for beam_axis in axes:
        apex_in_eye = predicted_tip - beam_axis * instrument.light_radius_mm / np.tan(angle)
        where, centre, ray_angles, radii = _predicted_rays(
            model,
            apex_in_eye,
            beam_axis,
            angle,
            eye.center_in_eye,
            eye.radius_mm,
            max_rays,
            camera.width_px,
            camera.height_px,
        )
        if where != _ON_IMAGE:
            status, detail = _REFUSALS[where]
            return PoseEstimate(status, detail=detail)
        fans.append(RayFan(centre, ray_angles, radii, align=True))
    return SpotPlan(
        fans=tuple(fans),
        beams=tuple(range(instrument.beam_count)),
        radii_px=tuple(float(fan.radii_px.mean()) for fan in fans),
        tip_in_eye=predicted_tip,
        beam_axes_in_eye=axes,
    )


def _fit_read_edges(
    setup: Setup, predicted: PoseEstimate, reading: LightReading, through_insertion: bool
) -> tuple[PoseEstimate, tuple[np.ndarray, ...], ConeSolution | None]:
    """Tracking's fit and judge stages: the read edges fitted from the predicted pose (Gauss-Newton; the shaft's
    points at the predicted pose left out), judged, the edge points it used and the fit (None when none ran)."""
    predicted_tip, predicted_axis = predicted.pose()
    hidden = hidden_by_shaft(setup, reading.edges_px, predicted_tip, predicted_axis)
    fit = fit_visible(
        setup,
        reading,
        hidden,
        predicted_tip,
        predicted_axis,
        predicted.roll,
        through_insertion=through_insertion,
        solver="gauss-newton",
    )
    if isinstance(fit, PoseEstimate):
        return fit, (), None
    return judge_fit(fit, setup, spots=setup.instrument.beam_count), fitted_edges_px(fit), fit


@njit(cache=True)
def _predicted_rays(
    model: np.ndarray,
    apex_in_eye: np.ndarray,
    beam_axis: np.ndarray,
    angle: float,
    eye_centre: np.ndarray,
    eye_radius: float,
    max_rays: int,
    width_px: int,
    height_px: int,
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """A beam's predicted edge in the image and the rays across it, compiled: one call per spot.

    The cone of ``angle`` (radians) from ``apex_in_eye`` (3,) along ``beam_axis`` (3,) meets the eye (mm) in
    ``_CURVE_POINTS`` points; ``model`` (:func:`spotnav.optics.camera.camera_model`) projects them. Returns which of
    ``_REFUSALS`` applies (``_ON_IMAGE``: none) and the rays of :func:`spotnav.image.rays.rays_through_curve`: their
    centre (2,), angles (R,) in radians and radii (R,) in pixels, one per two pixels of the curve, 64 to
    ``max_rays``.
    """
    none = np.empty(0)
    offset = apex_in_eye - eye_centre
    if not np.sum(offset * offset) < eye_radius * eye_radius:
        return _OUTSIDE_EYE, np.empty(2), none, none
    axis = beam_axis / np.sqrt(np.sum(beam_axis * beam_axis))
    curve_in_eye = cone_sphere_points(apex_in_eye, axis, angle, eye_centre, eye_radius, _CURVE_POINTS)
    curve_px = project_rows(model, curve_in_eye)
    if not np.all(np.isfinite(curve_px)):
        return _OFF_RETINA, np.empty(2), none, none
    perimeter = 0.0
    for n in range(len(curve_px)):
        following = curve_px[(n + 1) % len(curve_px)]
        perimeter += np.sqrt((following[0] - curve_px[n, 0]) ** 2 + (following[1] - curve_px[n, 1]) ** 2)
    low_u, low_v = curve_px[:, 0].min() - _BORDER_PX, curve_px[:, 1].min() - _BORDER_PX
    high_u, high_v = curve_px[:, 0].max() + _BORDER_PX, curve_px[:, 1].max() + _BORDER_PX
    if low_u < 0 or low_v < 0 or high_u > width_px - 1 or high_v > height_px - 1:
        return _AT_BORDER, np.empty(2), none, none
    centre, ray_angles, radii = curve_rays(curve_px, int(min(max(perimeter / 2.0, 64.0), max_rays)))
    return _ON_IMAGE, centre, ray_angles, radii


def prepare_kernels(setup: Setup) -> None:
    """Run tracking's compiled kernels, and the whole-frame method, once on synthetic spots and cones.

    They are compiled (or loaded from Numba's cache) on their first call: here, before the first
    frame, rather than during a tracked frame.
    """
    rows, columns = np.mgrid[:96, :96]
    noise = np.random.default_rng(0).normal(0.0, 3.0, (96, 96, 1))  # the noise beside the spot is read
    image = np.clip(np.round(20.0 + noise), 1, 254).astype(np.uint8).repeat(3, axis=2)
    image[(rows - 48) ** 2 + (columns - 48) ** 2 < 24**2] = 200
    circle = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)
    curve_px = 48 + 20 * np.column_stack([np.cos(circle), np.sin(circle)])
    edge = detect_edge_along_rays(image, *rays_through_curve(curve_px, 64), align=True)
    judge_edge(replace(edge, width_px=2.0 * edge.width_px), setup, 20.0, edge_angle(setup))
    light_grid, value_grid = response_curve(setup.camera.pixel_response)  # the edge model's kernels
    blur = frame_blur_for_width(0.5, 0.01, 3.0, 6.0, light_grid, value_grid)
    frame_blur_shift(0.5, 0.01, 3.0, blur, light_grid, value_grid)
    pooled_frame_blur(image[:, :, 0], 0, np.array([48.0, 48.0]), 26.0, 40.0, 255, new_noise_pool())  # as read
    fit_ellipse(curve_px)  # the whole-frame method's start, warmed even where the frame below cannot show a spot
    instrument, eye = setup.instrument, setup.eye
    tip_in_eye = eye.center_in_eye - np.array([0.0, 0.0, eye.radius_mm - 3.0])  # 3 mm above the pole: a whole spot
    axis = normalize(tip_in_eye - instrument.insertion_in_eye)
    angle = edge_angle(setup)
    beams = beam_axes(axis, instrument.beam_count, instrument.beam_tilt)
    curves = [cone_sphere_curve(tip_in_eye, beam, angle, eye.center_in_eye, eye.radius_mm, 64) for beam in beams]
    edges = [project_points(setup.camera, curve) for curve in curves]
    camera = setup.camera  # a tracked frame's rays
    _predicted_rays(
        camera_model(camera),
        tip_in_eye,
        beams[0],
        angle,
        eye.center_in_eye,
        eye.radius_mm,
        64,
        camera.width_px,
        camera.height_px,
    )
    problem = pose_problem(setup, edges, list(range(instrument.beam_count)), tip_in_eye + 0.01, axis, 0.0)
    for solver in ("gauss-newton", "levenberg-marquardt"):  # tracking's and acquisition's fits, and their checks
        fit = fit_cones(problem, solver=solver)
        judge_fit(fit, setup, spots=instrument.beam_count)
    axis_line(refit_free_axis(setup, fit))  # the sequence's test's free axis
    hidden_by_shaft(setup, edges, tip_in_eye, axis)
    # The whole-frame method once, on a frame of the camera's size with those spots drawn: its tables and first
    # calls are ready before the first frame too.
    frame = np.full((setup.camera.height_px, setup.camera.width_px, 3), 10, dtype=np.uint8)
    outlines = [np.round(edge[np.all(np.isfinite(edge), axis=1)]).astype(np.int32) for edge in edges]
    cv2.fillPoly(frame, [outline for outline in outlines if len(outline) > 2], (200, 200, 200))
    localize_precise(frame, setup)


@contextmanager
def frozen_heap() -> Iterator[None]:
    """Python's cyclic garbage collector leaves every object alive on entry alone inside (``gc.freeze``), and has
    them back on exit (``gc.unfreeze``), unless something was frozen before (an outer ``frozen_heap`` or the
    caller's own ``gc.freeze``: that stays frozen): wrap a real-time loop in it.

    With spotnav's modules loaded some 200 000 objects live, and a full collection walks them all (49 ms here). It
    comes when the objects kept since the last one reach a quarter of them: a loop that keeps a row per frame met a
    71 ms frame after 12 000 frames at 1024 px. Frozen, a full collection walks only what the loop kept (0.2 ms for
    20 000 objects), and the slowest of those 12 000 frames took 5.9 ms.
    """
    frozen_before = gc.get_freeze_count() > 0
    gc.freeze()
    try:
        yield
    finally:
        if not frozen_before:
            gc.unfreeze()


@dataclass
class Tracker:
    """Track the instrument over consecutive frames (see the module's docstring).

    Parameters
    ----------
    setup : Setup
    through_insertion : bool
        Constrain the axis through the insertion point (method ``precise``);
        ``False`` fits it (``precise-free``).
    max_jump_mm : float
        A tracked tip further than this from the prediction (re-acquired:
        from where it was last seen) is localized on the whole image instead.
    max_rays : int
        Most rays per spot in tracked frames.

    Attributes
    ----------
    sequence : AxesMeeting
        The running test of where the axes meet (method ``precise``: the
        freed axis of each frame answered or ``miscalibrated``, every one of
        the first ``_LISTEN_FRAMES``, then one in ``_LISTEN_EVERY``, whose
        pose is new to it). Once its verdict
        is given, every frame after it is ``mismatch`` (no pose) with that
        verdict: a setup the sequence contradicts biases every pose.
    """

    setup: Setup
    through_insertion: bool = True
    max_jump_mm: float = 0.5
    max_rays: int = 128
    _last: PoseEstimate | None = field(default=None, init=False, repr=False)
    _last_seen: PoseEstimate | None = field(default=None, init=False, repr=False)
    _lost_frames: int = field(default=0, init=False, repr=False)
    _velocity: np.ndarray | None = field(default=None, init=False, repr=False)
    _change: np.ndarray | None = field(default=None, init=False, repr=False)
    _steady: bool = field(default=False, init=False, repr=False)
    _rehearsal: LightReading | None = field(default=None, init=False, repr=False)
    _noise_pools: list[np.ndarray] = field(default_factory=list, init=False, repr=False)
    sequence: AxesMeeting = field(init=False, repr=False)
    _answered: int = field(default=0, init=False, repr=False)

    def __post_init__(self) -> None:
        check_localized_beams(self.setup.instrument)  # 2 or 4 beams: simulation only
        self.sequence = AxesMeeting(self.setup)
        if not (np.isfinite(self.max_jump_mm) and self.max_jump_mm > 0):
            raise ValueError(f"max_jump_mm must be a finite number > 0, got {self.max_jump_mm}")
        if self.max_rays < 64:
            raise ValueError(f"max_rays must be at least 64, got {self.max_rays}")
        prepare_kernels(self.setup)
        # The noise beside each beam's spot over the last frames: the stream's encoding blurs them alike.
        self._noise_pools = [new_noise_pool() for _ in range(self.setup.instrument.beam_count)]

    def update(self, image: np.ndarray) -> TrackedFrame:
        """Localize the next frame.

        Parameters
        ----------
        image : ndarray
            The frame, sRGB-encoded, 8 or 16 bits, the camera's size.
        """
        self._rehearsal = None
        for pool in self._noise_pools:
            advance_noise_pool(pool)
        predicted = self._predict()
        estimate, mode = None, "acquired"
        start, found = (predicted, "tracked") if predicted is not None else (self._last_seen, "reacquired")
        edges: tuple[np.ndarray, ...] = ()
        fit: ConeSolution | None = None
        if start is not None:
            tracked, edges, fit = _track_with_edges(
                image, self.setup, start, self.through_insertion, self.max_rays, self._noise_pools
            )
            if tracked.ok and np.linalg.norm(tracked.pose()[0] - start.pose()[0]) <= self.max_jump_mm:
                estimate, mode = tracked, found
            else:  # the noise was read beside a spot the frame may not hold there
                for pool in self._noise_pools:
                    discard_noise_reading(pool)
        if estimate is None:
            result = localize_precise_with_edges(image, self.setup, through_insertion=self.through_insertion)
            estimate, edges, fit = result.estimate, result.fitted_edges_px, result.fit
        if fit is not None and estimate.status in _HEARD:
            self._listen(fit)
        if not estimate.ok:
            self._forget()
            return TrackedFrame(estimate, "lost", edges)
        self._lost_frames = 0
        self._remember(estimate)
        if self.sequence.verdict:
            return TrackedFrame(_flagged(estimate, self.sequence.verdict), mode, edges)
        return TrackedFrame(estimate, mode, edges)

    def _listen(self, fit: ConeSolution) -> None:
        """A frame's axis freed (method ``precise``) and fed to the sequence's test while it listens (every frame
        of the first ``_LISTEN_FRAMES`` answered, then one in ``_LISTEN_EVERY``) and its pose is new to the test
        (:meth:`AxesMeeting.is_new`, asked before the free fit: a still hand costs nothing)."""
        self._answered += 1
        listening = self._answered <= _LISTEN_FRAMES or self._answered % _LISTEN_EVERY == 0
        tip = fit.tip()
        if self.through_insertion and listening and self.sequence.is_new(tip):
            self.sequence.add(axis_line(refit_free_axis(self.setup, fit)), pose_tip=tip)

    def rehearse(self, image: np.ndarray) -> None:
        """Track the last frame again from the last pose, a step a call, with the fewest rays, keeping nothing.

        Called again and again while the next frame is awaited, this keeps the
        code and data a tracked frame runs from in the core's caches: met
        cold, after a video decoder ran in the same thread, a tracked frame at
        2048 px took twice as long. The steps alternate: the edges along the
        rays, then their fit. Does nothing without a pose.

        Parameters
        ----------
        image : ndarray, shape (H, W, 3) or (H, W)
            The last frame given to :meth:`update`.
        """
        if self._last is None:
            return
        if self._rehearsal is None:
            pools = [pool.copy() for pool in self._noise_pools]  # as a tracked frame reads, keeping nothing
            for pool in pools:
                advance_noise_pool(pool)
            read = _read_predicted_edges(image, self.setup, self._last, _REHEARSAL_RAYS, pools)
            self._rehearsal = None if isinstance(read, PoseEstimate) else read
        else:
            _fit_read_edges(self.setup, self._last, self._rehearsal, self.through_insertion)
            self._rehearsal = None

    def _predict(self) -> PoseEstimate | None:
        last = self._last
        if last is None or last.tip_in_eye is None or last.axis is None:
            return None
        if self._velocity is None:
            return last
        step = self._velocity + self._change if self._steady else self._velocity
        return replace(last, tip_in_eye=last.tip_in_eye + step)

    def _remember(self, estimate: PoseEstimate) -> PoseEstimate:
        if self._last is not None and self._last.tip_in_eye is not None:
            velocity = estimate.pose()[0] - self._last.tip_in_eye
            change = None if self._velocity is None else velocity - self._velocity
            # The step's change continues a steady turn when it agrees with the change before it; the fit's noise
            # and a tremor sampled a few times a period change it at random or back and forth.
            self._steady = bool(
                change is not None
                and self._change is not None
                and np.linalg.norm(change - self._change) <= np.linalg.norm(change)
            )
            self._velocity, self._change = velocity, change
        self._last = self._last_seen = estimate
        return estimate

    def lose(self) -> None:
        """A frame without usable pixels (unreadable, or of the wrong size): lost, as a frame without its spot, so
        that a video's wrong-size frame (read, then refused) and a file's (refused unread, or in a replay) count
        alike."""
        self._forget()

    def _forget(self) -> None:
        self._last, self._velocity, self._change, self._steady = None, None, None, False
        self._lost_frames += 1
        if self._lost_frames > _MAX_LOST_FRAMES:
            self._last_seen = None
