"""Calibration from frames at known tip positions: the beam's edge angle and, optionally, two radii.

The precise method puts each spot's edge where the light is half of its full
value, at ``instrument.edge_half_angle_deg`` from the beam's axis. A real beam's
soft edge, a lens's blur or a camera's tone curve move that angle, so it is
measured: with the tip known (a robot reports it), every edge point's angle
from its beam's axis is a measurement of it. All frames' points are fitted at
once by robust least squares, together with each three-beam frame's roll and,
with ``fit_radius``, the retina's radius (the points are back-projected onto a
sphere of that radius, so only the true radius puts them all on cones of one
angle) and, with ``fit_light_radius``, the radius of the light's emitting face
(a light of finite size widens the edge by a distance, so by an angle that
grows as the tip nears the retina: only the true radius puts frames at all
heights on cones of one angle).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from spotnav.camera import unproject_pixels_to_sphere
from spotnav.config import Setup
from spotnav.detect import detect_edge_subpixel, detect_spots_otsu
from spotnav.geometry import angles_from_cone_axes, assign_beams, beam_axes, normalize
from spotnav.localize import (
    EdgeFrame,
    PoseEstimate,
    edge_half_angle,
    fit_height_correction,
    localize_precise_with_edges,
)
from spotnav.reconstruct import least_squares_covariance, robust_sigma

__all__ = [
    "Calibration",
    "HeightCorrection",
    "KnownFrame",
    "RadiusSelfCalibration",
    "calibrate_edge",
    "calibrate_height_correction",
    "prepare_self_calibration",
    "self_calibrate_radius",
]

MIN_FRAMES = 3
MIN_FRAMES_FOR_RADIUS = 5
MIN_SPREAD_FOR_RADIUS_MM = 1.0
MIN_HEIGHT_RATIO_FOR_LIGHT_RADIUS = 1.2
_CONTRAST_SIGMA = 4.0


@dataclass(frozen=True)
class KnownFrame:
    """A calibration frame and where the tip was.

    Attributes
    ----------
    name : str
        For messages.
    image : ndarray
        The frame, sRGB-encoded RGB or grey.
    tip_in_eye : ndarray, shape (3,)
        The known tip, mm.
    axis : ndarray, shape (3,), or None
        The known instrument axis; ``None``: from the insertion point to the tip.
    """

    name: str
    image: np.ndarray
    tip_in_eye: np.ndarray
    axis: np.ndarray | None = None


@dataclass(frozen=True)
class Calibration:
    """Fitted values, their 1-sigma uncertainties and the residuals before and after.

    Attributes
    ----------
    edge_half_angle_deg, edge_sigma_deg : float
    radius_mm : float
        Fitted radius, or the setup's when it was not fitted.
    radius_sigma_mm : float
        NaN when the radius was not fitted.
    light_radius_mm, light_radius_sigma_mm : float
        Fitted light radius (or the setup's) and its uncertainty (NaN when not fitted).
    rms_before_deg, rms_after_deg : float
        RMS angle of the inlying edge points from their cones with the setup's
        values and with the fitted ones.
    frames : int
        Frames used.
    points : int
        Edge points used.
    skipped : tuple of str
        Frames left out, with the reason.
    """

    edge_half_angle_deg: float
    edge_sigma_deg: float
    radius_mm: float
    radius_sigma_mm: float
    light_radius_mm: float
    light_radius_sigma_mm: float
    rms_before_deg: float
    rms_after_deg: float
    frames: int
    points: int
    skipped: tuple[str, ...] = ()

    def apply(self, setup: Setup) -> Setup:
        """The setup with the fitted edge angle (and radii) in place."""
        instrument = replace(
            setup.instrument, edge_half_angle_deg=self.edge_half_angle_deg, light_radius_mm=self.light_radius_mm
        )
        eye = replace(setup.eye, radius_mm=self.radius_mm)
        return replace(setup, eye=eye, instrument=instrument)


@dataclass(frozen=True)
class _FrameEdges:
    pixels: np.ndarray  # (N, 2)
    beam_of_point: np.ndarray  # (N,)
    group_of_point: np.ndarray  # (N,) one group per spot
    tip: np.ndarray
    axis: np.ndarray
    roll: float


def _frame_edges(frame: KnownFrame, setup: Setup, group: int) -> _FrameEdges | str:
    """The frame's edge pixels, the beam of each and the starting roll, or why the frame cannot be used."""
    instrument = setup.instrument
    if frame.image.shape[:2] != (setup.camera.height_px, setup.camera.width_px):
        return f"{frame.name}: image is {frame.image.shape[1]}x{frame.image.shape[0]} px, not the setup's size"
    spots = detect_spots_otsu(frame.image, min_contrast_sigma=_CONTRAST_SIGMA).spots
    if len(spots) != instrument.beam_count or any(s.touches_border for s in spots):
        return f"{frame.name}: {len(spots)} whole spots, need {instrument.beam_count}"
    tip = np.asarray(frame.tip_in_eye, dtype=float)
    axis = normalize(frame.axis if frame.axis is not None else tip - instrument.insertion_in_eye)
    pixels = [detect_edge_subpixel(frame.image, spot).pixels for spot in spots]
    beams, roll = [0], 0.0
    if len(spots) > 1:
        centres = np.array(
            [unproject_pixels_to_sphere(setup.camera, p.mean(axis=0), setup.eye.radius_mm) for p in pixels]
        )
        assignment = assign_beams(centres - tip, axis)
        if assignment is None:
            return f"{frame.name}: cannot tell which spot each beam made"
        beams, roll = assignment
    return _FrameEdges(
        np.concatenate(pixels),
        np.concatenate([np.full(len(p), b) for p, b in zip(pixels, beams, strict=True)]),
        np.concatenate([np.full(len(p), group + k) for k, p in enumerate(pixels)]),
        tip,
        axis,
        roll,
    )


def _residuals(
    params: np.ndarray, frames: list[_FrameEdges], setup: Setup, fit_radius: bool, fit_light_radius: bool
) -> np.ndarray:
    """Edge points' angles from their cones; ``params``: edge, [radius], [light radius], rolls."""
    edge = params[0]
    radius = params[1] if fit_radius else setup.eye.radius_mm
    light_radius = params[1 + fit_radius] if fit_light_radius else setup.instrument.light_radius_mm
    rolls = params[1 + fit_radius + fit_light_radius :]
    instrument = setup.instrument
    out = []
    for f, frame in enumerate(frames):
        points = unproject_pixels_to_sphere(setup.camera, frame.pixels, radius)
        roll = rolls[f] if instrument.beam_count > 1 else 0.0
        axes = beam_axes(frame.axis, instrument.beam_count, instrument.beam_tilt, roll)[frame.beam_of_point]
        angle = angles_from_cone_axes(points - frame.tip, axes, light_radius)
        out.append(np.nan_to_num(angle - edge, nan=1.0))  # a point off the sphere is a gross misfit
    return np.concatenate(out)


def calibrate_edge(
    frames: Sequence[KnownFrame], setup: Setup, *, fit_radius: bool = False, fit_light_radius: bool = False
) -> Calibration:
    """Fit the edge angle (and the eye's radius) to frames at known tip positions.

    Parameters
    ----------
    frames : sequence of KnownFrame
    setup : Setup
        The eye, camera and instrument; its edge angle and radius are the
        starting values and the "before" of the residuals.
    fit_radius : bool
        Fit ``eye.radius_mm`` too.
    fit_light_radius : bool
        Fit ``instrument.light_radius_mm`` too (a light of finite size widens
        the edge more, in angle, the closer the tip; the known tips' heights
        above the pole must differ by a factor of
        ``MIN_HEIGHT_RATIO_FOR_LIGHT_RADIUS`` or more).

    Raises
    ------
    ValueError
        Too few usable frames (3, or 5 with ``fit_radius``), or known tips too
        close together to tell the radius (they must spread over 1 mm in x, y).
    """
    edges, skipped = [], []
    for frame in frames:
        result = _frame_edges(frame, setup, 3 * len(edges))
        (skipped if isinstance(result, str) else edges).append(result)
    needed = MIN_FRAMES_FOR_RADIUS if fit_radius else MIN_FRAMES
    if len(edges) < needed:
        reasons = "; ".join(skipped) if skipped else "none given"
        raise ValueError(f"calibration needs at least {needed} usable frames, got {len(edges)} ({reasons})")
    if fit_radius:
        tips = np.array([e.tip for e in edges])
        spread = float(np.max(np.ptp(tips[:, :2], axis=0)))
        if spread < MIN_SPREAD_FOR_RADIUS_MM:
            raise ValueError(
                f"the known tips spread {spread:.2f} mm in x, y; fitting the radius needs at least "
                f"{MIN_SPREAD_FOR_RADIUS_MM:g} mm (degenerate poses)"
            )
    if fit_light_radius:
        heights = np.array([e.tip[2] for e in edges])
        if np.max(heights) < MIN_HEIGHT_RATIO_FOR_LIGHT_RADIUS * max(float(np.min(heights)), 1e-9):
            raise ValueError(
                f"the known tips lie {np.min(heights):.2f}-{np.max(heights):.2f} mm above the pole; "
                f"fitting the light's radius needs a ratio of {MIN_HEIGHT_RATIO_FOR_LIGHT_RADIUS:g} or more"
            )
    start = [edge_half_angle(setup)] + ([setup.eye.radius_mm] if fit_radius else [])
    start += [setup.instrument.light_radius_mm] if fit_light_radius else []
    start += [e.roll for e in edges] if setup.instrument.beam_count > 1 else []
    args = (edges, setup, fit_radius, fit_light_radius)
    before = _residuals(np.array(start), *args)
    scale = max(robust_sigma(before, True), 1e-6)
    robust = least_squares(_residuals, start, args=args, loss="soft_l1", f_scale=scale, x_scale="jac")
    spread = max(robust_sigma(robust.fun, False), 1e-7)
    inliers = np.abs(robust.fun) < 3.0 * spread
    groups = np.concatenate([e.group_of_point for e in edges])
    jacobian = robust.jac[inliers]
    covariance = least_squares_covariance(jacobian, robust.fun[inliers], groups[inliers])[0]
    sigmas = np.sqrt(np.diag(covariance))
    light_radius = setup.instrument.light_radius_mm
    if fit_light_radius:  # a light smaller than the fit can tell may come out a little below zero: a point
        light_radius = max(float(robust.x[1 + fit_radius]), 0.0)
    return Calibration(
        edge_half_angle_deg=float(np.degrees(robust.x[0])),
        edge_sigma_deg=float(np.degrees(sigmas[0])),
        radius_mm=float(robust.x[1]) if fit_radius else setup.eye.radius_mm,
        radius_sigma_mm=float(sigmas[1]) if fit_radius else float("nan"),
        light_radius_mm=light_radius,
        light_radius_sigma_mm=float(sigmas[1 + fit_radius]) if fit_light_radius else float("nan"),
        rms_before_deg=float(np.degrees(np.sqrt(np.mean(before[inliers] ** 2)))),
        rms_after_deg=float(np.degrees(np.sqrt(np.mean(robust.fun[inliers] ** 2)))),
        frames=len(edges),
        points=int(inliers.sum()),
        skipped=tuple(skipped),
    )


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
    """Section 5.5's factor averaged over frames at known tips (:func:`spotnav.localize.fit_height_correction`).

    Raises
    ------
    ValueError
        When no frame gives a factor.
    """
    factors, skipped = [], []
    for frame in frames:
        try:
            factors.append(fit_height_correction(frame.image, setup, frame.tip_in_eye))
        except ValueError as error:
            skipped.append(f"{frame.name}: {error}")
    if not factors:
        raise ValueError(f"no frame gives a height correction ({'; '.join(skipped)})")
    return HeightCorrection(float(np.mean(factors)), float(np.std(factors)), len(factors), tuple(skipped))


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


def _joint_residuals(params: np.ndarray, frames: list[_FrameEdges], setup: Setup, edge: float) -> np.ndarray:
    instrument = setup.instrument
    radius = params[0]
    per_frame = 4 if instrument.beam_count > 1 else 3
    out = []
    for f, frame in enumerate(frames):
        block = params[1 + per_frame * f : 1 + per_frame * (f + 1)]
        tip = block[:3]
        axis = normalize(tip - instrument.insertion_in_eye)
        roll = block[3] if per_frame == 4 else 0.0
        axes = beam_axes(axis, instrument.beam_count, instrument.beam_tilt, roll)[frame.beam_of_point]
        rays = unproject_pixels_to_sphere(setup.camera, frame.pixels, radius) - tip
        angle = angles_from_cone_axes(rays, axes, instrument.light_radius_mm)
        out.append(np.nan_to_num(angle - edge, nan=1.0))
    return np.concatenate(out)


def prepare_self_calibration(image: np.ndarray, setup: Setup) -> tuple[PoseEstimate, EdgeFrame | None]:
    """One frame's share of :func:`self_calibrate_radius`: its precise pose and its edges (None if unusable)."""
    estimate, prepared = localize_precise_with_edges(image, setup)
    return estimate, prepared if estimate.ok else None


def self_calibrate_radius(
    frames_or_images: Sequence[np.ndarray] | Sequence[tuple[PoseEstimate, EdgeFrame | None]], setup: Setup
) -> RadiusSelfCalibration:
    """Fit one eye radius and every frame's pose together, without known poses.

    Only the true radius puts every frame's back-projected edge on a right
    circular cone of the edge angle with its axis through the insertion point,
    so the radius is fitted with all poses at once (robust least squares with
    a sparse Jacobian), starting from each frame's precise fit at the setup's
    radius.

    Parameters
    ----------
    frames_or_images : sequence
        The frames, or what :func:`prepare_self_calibration` made of each
        (so that frames can be prepared elsewhere, in parallel).
    setup : Setup

    Raises
    ------
    ValueError
        With fewer than 20 usable frames.
    """
    shares = [f if isinstance(f, tuple) else prepare_self_calibration(f, setup) for f in frames_or_images]
    estimates = [estimate for estimate, _ in shares]
    frames, used = [], []
    for index, (estimate, prepared) in enumerate(shares):
        if prepared is None:
            continue
        assert estimate.tip_in_eye is not None
        pixels = np.concatenate(prepared.edges_px)
        beams = np.concatenate([np.full(len(e), b) for e, b in zip(prepared.edges_px, prepared.beams, strict=True)])
        groups = np.concatenate([np.full(len(e), 3 * len(frames) + k) for k, e in enumerate(prepared.edges_px)])
        frames.append(_FrameEdges(pixels, beams, groups, estimate.tip_in_eye, prepared.axis, prepared.roll))
        used.append(index)
    if len(frames) < MIN_FRAMES_FOR_SELF_CALIBRATION:
        raise ValueError(
            f"fitting the radius from the frames alone needs at least {MIN_FRAMES_FOR_SELF_CALIBRATION} frames "
            f"with a pose, got {len(frames)}"
        )
    per_frame = 4 if setup.instrument.beam_count > 1 else 3
    start = [setup.eye.radius_mm]
    for frame in frames:
        start += [*frame.tip, frame.roll][:per_frame]
    sizes = [len(f.pixels) for f in frames]
    sparsity = lil_matrix((sum(sizes), len(start)), dtype=int)
    sparsity[:, 0] = 1
    row = 0
    for f, size in enumerate(sizes):
        sparsity[row : row + size, 1 + per_frame * f : 1 + per_frame * (f + 1)] = 1
        row += size
    edge = edge_half_angle(setup)
    args = (frames, setup, edge)
    first = _joint_residuals(np.array(start), *args)
    scale = max(robust_sigma(first, True), 1e-6)
    fit = least_squares(
        _joint_residuals, start, args=args, jac_sparsity=sparsity, loss="soft_l1", f_scale=scale, x_scale="jac"
    )
    spread = max(robust_sigma(fit.fun, False), 1e-7)
    inliers = np.abs(fit.fun) < 3.0 * spread
    jacobian = fit.jac.tocsr()[inliers].toarray()
    groups = np.concatenate([f.group_of_point for f in frames])
    covariance = least_squares_covariance(jacobian, fit.fun[inliers], groups[inliers])[0]
    radius = float(fit.x[0])
    camera = setup.camera
    ends = np.cumsum(sizes)
    for f, index in enumerate(used):
        block = slice(1 + per_frame * f, 1 + per_frame * f + 3)
        tip = fit.x[block]
        points = unproject_pixels_to_sphere(camera, frames[f].pixels, radius)
        kept = inliers[ends[f] - sizes[f] : ends[f]]
        scale_px = np.linalg.norm(points - tip, axis=1) * camera.focal_px / (camera.distance_mm - points[:, 2])
        residual_px = fit.fun[ends[f] - sizes[f] : ends[f]] * scale_px
        estimates[index] = replace(
            estimates[index],
            tip_in_eye=tip.copy(),
            axis=normalize(tip - setup.instrument.insertion_in_eye),
            sigma_mm=float(np.sqrt(np.trace(covariance[block, block]) / 3)),
            rms_px=float(np.sqrt(np.mean(residual_px[kept] ** 2))),
            other_axis=None,
            detail=f"eye radius fitted over {len(frames)} frames: {radius:.3f} mm",
        )
    return RadiusSelfCalibration(radius, float(np.sqrt(covariance[0, 0])), estimates, len(frames))
