"""The calibration job: the camera's response and the light's soft band chosen for the joint geometry fit, and
the thesis method's height correction, from frames at known poses.

:func:`calibrate` runs the geometry fit of :mod:`spotnav.pose.calibration`.
When the setup does not state the camera's response (``camera.response``),
the frames are calibrated through each of :data:`RESPONSE_CANDIDATES`, and
the reading whose spots agree best with the calibrated edge model (the RMS of
their mean offsets from their cones) is kept if it beats sRGB's by
:data:`RESPONSE_MARGIN`: a wrong response moves each spot's halfway level by a
fraction of its step that depends on its brightness, so spots of different
brightness disagree. Power laws differ little that way (read through another
gamma, a spot on a dark background moves by the same fraction of its step,
which the edge angle absorbs): a linear or gamma camera must be stated. Where
known frames' spots clip, the soft band they are read with is chosen the same
way (:data:`EDGE_BAND_FACTORS`), and so is the lens's aperture where the setup states none
(:data:`LIGHT_BLURS_PX`, then refined with its 1 sigma). :func:`check_held_out` localizes each known
frame with a calibration of the others (:data:`HELD_OUT_FOLDS`-fold cross-validation).
:func:`calibrate_height_correction` averages section 5.5's factor over the frames.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from spotnav.errors import InputError, SpotnavError
from spotnav.optics.defocus import spot_light_blur_px
from spotnav.optics.light import edge_angle
from spotnav.pose.calibration import (
    MIN_FRAMES,
    MIN_INLIER_FRACTION,
    Calibration,
    GeometryFit,
    HeldOut,
    finish_calibration,
    fit_geometry,
    refit,
)
from spotnav.pose.conefit.parameters import PARAMETER_GROUPS
from spotnav.pose.known_frame import KnownFrame
from spotnav.pose.localize import localize
from spotnav.pose.thesis import fit_height_correction
from spotnav.setup.config import Setup
from spotnav.setup.geometry import normalize
from spotnav.setup.values import SetupError

__all__ = [
    "APERTURE_MARGIN",
    "EDGE_BAND_FACTORS",
    "EDGE_BAND_MARGIN",
    "HELD_OUT_FOLDS",
    "LIGHT_BLURS_PX",
    "RESPONSE_CANDIDATES",
    "RESPONSE_MARGIN",
    "HeightCorrection",
    "calibrate",
    "calibrate_height_correction",
    "check_held_out",
    "with_edge_band",
]

# The responses told apart when the setup states none: sRGB (the default reading) and a tone curve. Power laws
# (linear, gammas) are not tried: on a textured retina a reading that compresses the texture makes the spots agree
# better whatever the camera wrote (measured on spotnav's renderer: sRGB frames agree best read as linear).
RESPONSE_CANDIDATES: tuple[str | float, ...] = ("srgb", "agx")
# A reading's spots must agree this much better than sRGB's to replace it. Measured: AgX frames read as AgX agree
# 23-72 % better (the Cycles sets) and 84 % (spotnav's renderer); sRGB frames read as AgX agree worse.
RESPONSE_MARGIN = 0.15
# The soft bands tried where known frames' spots clip, as factors of the setup's (instrument.edge_band_deg, by default
# 2 (beta - edge)), and how much better than the setup's a band's spots must agree to replace it. Measured on
# spotnav's renderer (768 px, +4.5 stops, blend 0.1 against the default 0.15): the spots' RMS offset 0.065 px at the
# setup's band, 0.019 at 0.45 times it; helix tips 0.0028 / 0.0062 mm. On cycles-photometry the spread is a noisier
# witness (docs/methods.md, calibration 9.).
EDGE_BAND_FACTORS = (0.45, 0.65, 0.8, 1.0, 1.25, 1.6)
EDGE_BAND_MARGIN = 0.15
# The held-out check's folds: each calibration leaves a quarter of the known frames out.
HELD_OUT_FOLDS = 4
# The lens's blurs tried where known frames' spots clip and the setup states no aperture (camera.aperture_mm): each
# the median over the known spots of the light's blur at their centres (sigma, pixels), by the aperture that gives
# it; and how much better than a pinhole's a blur's spots must agree to be kept. A blur of the light and a dimmer
# light trade along one clipped flank; spots at other depths are blurred by other amounts, and only the right
# aperture lets them all agree with the known poses.
LIGHT_BLURS_PX = (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)
APERTURE_MARGIN = 0.15
_WIDEST_BAND_DEG = 44.0  # instrument.edge_band_deg is under 45 deg
_WIDEST_APERTURE_MM = 1000.0  # camera.aperture_mm's limit


def calibrate(
    frames: Sequence[KnownFrame],
    setup: Setup,
    *,
    fit: Sequence[str] = (),
    fix: Sequence[str] = (),
    held_out: bool = True,
) -> Calibration:
    """Fit the geometry that frames at known poses determine (:mod:`spotnav.pose.calibration`), read through the
    response, soft band and lens aperture whose spots agree best (see the module's docstring), and check it on
    frames it has not seen (:func:`check_held_out`).

    Parameters
    ----------
    frames : sequence of KnownFrame
    setup : Setup
        The eye, camera and instrument to start from, and how well they are
        known (``[uncertainty]`` or ``[calibration]``): the priors of the
        first fit, the yardstick of "determined", and the uncertainty of what
        stays fixed.
    fit : sequence of str
        Groups of :data:`~spotnav.pose.conefit.parameters.PARAMETER_GROUPS` to fit whatever
        the frames say (an error when they cannot determine them).
    fix : sequence of str
        Groups to keep at the setup's values.
    held_out : bool
        Cross-validate (:attr:`Calibration.held_out`); the calibration returned is the one of all frames.

    Raises
    ------
    InputError
        Unknown group names; fewer than :data:`~spotnav.pose.calibration.MIN_FRAMES` usable frames; a
        forced group the frames cannot determine; known axes that are
        (nearly) parallel; or a calibrated model whose edge points still miss
        their cones (RMS over 0.1 deg and 1 px).
    """
    for name in (*fit, *fix):
        if name not in PARAMETER_GROUPS:
            raise InputError(f"{name!r} is not a parameter group, allowed: {', '.join(PARAMETER_GROUPS)}")
    if "beam-tilt" in fit and setup.instrument.beam_count == 1:
        raise InputError("one beam has no tilt: leave --fit beam-tilt out")
    both = sorted(set(fit) & set(fix))
    if both:
        raise InputError(f"{both[0]} cannot be both fitted and fixed")
    setup = with_edge_band(setup)
    responses: tuple[tuple[str | float, float], ...] = ()
    try:
        if setup.camera.response is not None:
            chosen = fit_geometry(frames, setup, fit, fix)
        else:
            chosen, responses = _choose_response(frames, setup, fit, fix)
    except SetupError as error:  # the fit left the geometry's allowed ranges: the frames do not read as the setup's
        raise InputError(
            f"the known frames' edges, read with the setup's light and camera, drove the geometry out of its allowed "
            f"range ({error}): check the setup's beam (count, angles) and known.csv; where the spots clip, a lens's "
            "blur the setup does not state can do this: state camera.aperture_mm"
        ) from error
    chosen, bands = _choose_edge_band(frames, chosen, fit, fix)
    pinhole = chosen
    chosen, apertures, aperture_sigma = _choose_aperture(frames, chosen, fit, fix)
    try:
        result = finish_calibration(chosen)
    except SpotnavError:
        if chosen is pinhole:
            raise
        # Its frames left out in turn, the lens's fit left the geometry's ranges: the aperture is not kept.
        aperture_sigma = 0.0
        result = finish_calibration(pinhole)
    if aperture_sigma > 0.0:
        record = replace(result.setup.calibration, aperture_sigma_mm=aperture_sigma)
        result = replace(result, setup=replace(result.setup, calibration=record))
    result = replace(result, responses=responses, edge_bands=bands, apertures=apertures)
    return replace(result, held_out=check_held_out(frames, chosen)) if held_out else result


def check_held_out(frames: Sequence[KnownFrame], fitted: GeometryFit, folds: int = HELD_OUT_FOLDS) -> HeldOut | None:
    """Each known frame localized (the precise method, as ``localize`` does) with the calibration of the others.

    ``folds``-fold cross-validation: fold ``k`` leaves out every ``folds``-th of the frames the fit used (from the
    ``k``-th on, so each fold spans the poses), calibrates from the rest (:func:`~spotnav.pose.calibration.refit`:
    the parameters, response and soft band that all the frames chose, fitted anew, with the calibration's check
    and covariance) and localizes the frames left out. None when too few frames would be left to calibrate a fold
    from. Choosing the model from all the frames leaks a little of the frames left out into it; choosing it again in
    each fold cost some 2.5 times the calibration itself.

    Parameters
    ----------
    frames : sequence of KnownFrame
        The frames ``fitted`` was given (``fitted.used`` indexes them).
    fitted : GeometryFit
    folds : int
    """
    count = len(fitted.edges)
    folds = min(folds, count)
    if count - -(-count // folds) < MIN_FRAMES:
        return None
    names, statuses, errors, sigmas = [""] * count, ["refused"] * count, [np.nan] * count, [np.nan] * count
    for fold in range(folds):
        out = list(range(fold, count, folds))
        try:
            calibrated = finish_calibration(refit(fitted, [k for k in range(count) if k not in out])).setup
        except SpotnavError:  # the other frames do not calibrate alone: the frames left out stay refused
            calibrated = None
        for k in out:
            frame = frames[fitted.used[k]]
            names[k] = frame.name
            if calibrated is None:
                continue
            estimate = localize(frame.image, calibrated, "precise")
            statuses[k] = estimate.status
            if estimate.ok and estimate.tip_in_eye is not None:
                errors[k] = float(np.linalg.norm(estimate.tip_in_eye - frame.tip_in_eye))
                sigmas[k] = estimate.sigma_mm
    return HeldOut(folds, tuple(names), tuple(statuses), tuple(errors), tuple(sigmas))


def _choose_response(
    frames: Sequence[KnownFrame], setup: Setup, fit: Sequence[str], fix: Sequence[str]
) -> tuple[GeometryFit, tuple[tuple[str | float, float], ...]]:
    """The calibration through the response whose spots agree best (the module's docstring), and each response's
    spread (:attr:`Calibration.responses`)."""
    fits: list[GeometryFit | None] = []
    for response in RESPONSE_CANDIDATES:
        reading = replace(setup, camera=replace(setup.camera, response=response))
        try:
            fits.append(fit_geometry(frames, reading, fit, fix))
        except SpotnavError:  # no usable frames, or a geometry out of its allowed ranges: not this response
            if response == RESPONSE_CANDIDATES[0]:
                raise  # the default reading's own reason
            fits.append(None)
    best, chosen, spreads = _most_agreeing(fits, RESPONSE_MARGIN)
    if best == 0:  # not told apart from the default reading: the response stays unstated
        chosen = replace(chosen, setup=replace(chosen.setup, camera=replace(chosen.setup.camera, response=None)))
    return chosen, tuple((r, float(v)) for r, v in zip(RESPONSE_CANDIDATES, spreads, strict=True))


def _most_agreeing(fits: Sequence[GeometryFit | None], margin: float) -> tuple[int, GeometryFit, list[float]]:
    """Which of calibrations through other readings of the same frames (the first the setup's, never None) to keep,
    and which it is: the one whose spots agree best (:meth:`GeometryFit.spot_spread_px`) if it beats the first's by
    ``margin``; and each one's spread (NaN where it failed or kept under half its points).

    A reading may use fewer of the frames (a band under a pixel reads no flank): its spread is over those it read.
    Required to read them all, the renderer's sharper beam (blend 0.1, 768 px) kept a band of 0.45 deg (0.0051 /
    0.0227 mm on the helix) where 0.31 deg, with which two of its eight frames are left out, gives 0.0028 / 0.0062.
    """
    spreads = [_spread(f) for f in fits]
    best = int(np.nanargmin(spreads)) if np.any(np.isfinite(spreads)) else 0
    if np.isfinite(spreads[0]) and not spreads[best] < (1.0 - margin) * spreads[0]:
        best = 0
    read = {index: f for index, f in enumerate(fits) if f is not None}  # a finite spread's, or the first
    return best, read[best], spreads


def _spread(fitted: GeometryFit | None) -> float:
    """A calibration's spots' spread (:meth:`GeometryFit.spot_spread_px`); NaN where it failed, kept under half its
    points, or fitted a geometry out of its allowed ranges (not this reading)."""
    if fitted is None or fitted.solution.inliers.mean() < MIN_INLIER_FRACTION:
        return float("nan")
    try:
        return fitted.spot_spread_px()
    except SetupError:
        return float("nan")


def with_edge_band(setup: Setup) -> Setup:
    """``setup`` with its light model's soft band stated (``instrument.edge_band_deg``, by default ``2 (beta -
    edge)`` at its edge): a calibration that moves the edge keeps the band its frames were read with."""
    instrument = setup.instrument
    if instrument.edge_band_deg is not None:
        return setup
    band = 2.0 * max(instrument.beam_half_angle - edge_angle(setup), 0.0)
    return replace(setup, instrument=replace(instrument, edge_band_deg=min(float(np.degrees(band)), _WIDEST_BAND_DEG)))


def _choose_edge_band(
    frames: Sequence[KnownFrame], fitted: GeometryFit, fit: Sequence[str], fix: Sequence[str]
) -> tuple[GeometryFit, tuple[tuple[float, float], ...]]:
    """Where a known frame's spot clips (read from its flank, :func:`spotnav.image.clipped.fit_clipped_edges`), the
    calibration through the soft band (:data:`EDGE_BAND_FACTORS` of the setup's) whose spots agree best, if it
    beats the setup's by :data:`EDGE_BAND_MARGIN`; and each band's spread (:attr:`Calibration.edge_bands`).

    A band too narrow or too wide moves each clipped spot's edge by an amount that depends on how far its
    plateau is over full scale: spots of different brightness then disagree, which no geometry absorbs.
    """
    clipped = any(np.isfinite(edge.log_amplitude) for frame in fitted.edges for edge in frame.light().edges)
    nominal = fitted.setup.instrument.edge_band_deg
    if not clipped or nominal is None or nominal == 0.0:
        return fitted, ()
    # A band's inner side stays outside the beam's axis (under twice the edge angle).
    widest = 0.99 * 2.0 * float(np.degrees(edge_angle(fitted.setup)))
    bands = [nominal] + [min(factor * nominal, widest) for factor in EDGE_BAND_FACTORS if factor != 1.0]
    fits: list[GeometryFit | None] = [fitted]
    for band in bands[1:]:
        # The fit's own starting setup (the response it read with, the insertion point its axes gave).
        setup = replace(fitted.setup, instrument=replace(fitted.setup.instrument, edge_band_deg=band))
        try:
            fits.append(fit_geometry(frames, setup, fit, fix))
        except SpotnavError:  # too few frames read with this band (a band under a pixel reads no flank), or a
            # geometry out of its allowed ranges: not this band
            fits.append(None)
    _, chosen, spreads = _most_agreeing(fits, EDGE_BAND_MARGIN)
    return chosen, tuple((float(b), float(s)) for b, s in zip(bands, spreads, strict=True))


def _choose_aperture(
    frames: Sequence[KnownFrame], fitted: GeometryFit, fit: Sequence[str], fix: Sequence[str]
) -> tuple[GeometryFit, tuple[tuple[float, float], ...], float]:
    """Where a known frame's spot clips and the setup states no aperture (``camera.aperture_mm``): the calibration
    through the aperture (by :data:`LIGHT_BLURS_PX`) whose spots agree best, if it beats a pinhole's by
    :data:`APERTURE_MARGIN`, refined by a parabola through its neighbours' agreement; each aperture tried with its
    spread (:attr:`Calibration.apertures`); and the fitted aperture's 1 sigma (0: none fitted).

    The spots' mean offsets from their cones ``o_s(A)``: ``sum_s o_s^2`` is about ``N (s0^2 + c (A - A0)^2)`` over
    ``N`` spots, and a least-squares ``A0`` has variance ``s0^2 / (N c)``.
    """
    setup = fitted.setup
    clipped = any(np.isfinite(edge.log_amplitude) for frame in fitted.edges for edge in frame.light().edges)
    if not clipped or setup.camera.aperture_mm is not None:
        return fitted, (), 0.0
    insertion = setup.instrument.insertion_in_eye
    axes = [normalize(f.tip_in_eye - insertion if f.axis is None else f.axis) for f in frames]
    per_mm = float(
        np.median([spot_light_blur_px(setup, f.tip_in_eye, a, 1.0) for f, a in zip(frames, axes, strict=True)])
    )
    if not per_mm > 0.0:
        return fitted, (), 0.0
    apertures = [min(blur / per_mm, _WIDEST_APERTURE_MM) for blur in LIGHT_BLURS_PX]
    fits: list[GeometryFit | None] = [fitted]
    for aperture in apertures[1:]:
        fits.append(_fit_with_aperture(frames, setup, aperture, fit, fix))
    best, chosen, spreads = _most_agreeing(fits, APERTURE_MARGIN)
    tried = tuple((float(a), float(v)) for a, v in zip(apertures, spreads, strict=True))
    if best == 0:
        return fitted, tried, 0.0
    spots = len(np.unique(chosen.solution.problem.points.spot))
    low, high = max(best - 1, 0), min(best + 1, len(apertures) - 1)
    near = [k for k in range(low, high + 1) if np.isfinite(spreads[k])]
    aperture, sigma = apertures[best], 0.5 * (apertures[high] - apertures[low])
    if len(near) == 3:
        x, y = np.array(apertures)[near], np.square(np.array(spreads)[near])
        c, b, _ = np.polyfit(x, y, 2)
        if c > 0.0:
            aperture = float(np.clip(-b / (2.0 * c), apertures[low], apertures[high]))
            sigma = float(spreads[best] / np.sqrt(spots * c))
    refined = _fit_with_aperture(frames, setup, aperture, fit, fix)
    if refined is None or not refined.spot_spread_px() <= spreads[best]:
        refined, aperture = chosen, apertures[best]
    return refined, tried, max(sigma, 1e-6)


def _fit_with_aperture(
    frames: Sequence[KnownFrame], setup: Setup, aperture_mm: float, fit: Sequence[str], fix: Sequence[str]
) -> GeometryFit | None:
    """The calibration with the lens's aperture ``aperture_mm`` stated (None: too few frames read with it, or a
    geometry out of its allowed ranges: not this aperture)."""
    try:
        return fit_geometry(frames, replace(setup, camera=replace(setup.camera, aperture_mm=aperture_mm)), fit, fix)
    except SpotnavError:
        return None


@dataclass(frozen=True)
class HeightCorrection:
    """The thesis method's height correction (section 5.5) from frames at known tips.

    Attributes
    ----------
    factor : float
        Mean of the frames' factors (``instrument.height_correction``).
    spread : float
        Their standard deviation.
    frames : int
        Frames used.
    skipped : tuple of str
        Frames left out, with the reason.
    """

    factor: float
    spread: float
    frames: int
    skipped: tuple[str, ...] = ()


def calibrate_height_correction(frames: Sequence[KnownFrame], setup: Setup) -> HeightCorrection:
    """Section 5.5's factor averaged over frames at known tips (:func:`spotnav.pose.thesis.fit_height_correction`).

    Raises
    ------
    InputError
        When no frame gives a factor.
    """
    factors, skipped = [], []
    for frame in frames:
        fitted = fit_height_correction(frame.image, setup, frame.tip_in_eye)
        if fitted.ok:
            factors.append(fitted.factor)
        else:  # the frame's reason (no whole spot, too many, the wrong size)
            skipped.append(f"{frame.name}: {fitted.detail}")
    if not factors:
        raise InputError(f"no frame gives a height correction ({'; '.join(skipped)})")
    return HeightCorrection(float(np.mean(factors)), float(np.std(factors)), len(factors), tuple(skipped))
