"""A calibration job: ``calibrate``'s application, from frames at known poses to a calibrated setup and its report.

:func:`run_calibration` reads the known poses and their images (an unreadable
image is left out with a warning), runs :func:`spotnav.app.calibrate.calibrate`,
merges the thesis method's height correction if asked, and returns the
calibrated setup with the lines that report it (:func:`calibration_lines`); the
caller prints them and writes the setup.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from spotnav.app.calibrate import APERTURE_MARGIN, EDGE_BAND_MARGIN, calibrate, calibrate_height_correction
from spotnav.app.progress import progress
from spotnav.app.session import ready, to_stderr
from spotnav.errors import SpotnavError
from spotnav.files.images import ImageReadError, read_image
from spotnav.files.poses import read_known_poses
from spotnav.pose.calibration import Calibration
from spotnav.pose.conefit.parameters import PARAMETER_GROUPS
from spotnav.pose.determined import unit_of
from spotnav.pose.known_frame import KnownFrame
from spotnav.setup.config import Setup
from spotnav.setup.uncertainty import GEOMETRY_PARAMETERS

__all__ = ["CalibrationJob", "calibration_lines", "run_calibration"]


@dataclass(frozen=True)
class CalibrationJob:
    """A calibration's outcome: the calibrated setup (with the height correction if asked) and its report's lines."""

    setup: Setup
    lines: tuple[str, ...]


def run_calibration(
    setup: Setup,
    poses: str | Path,
    images: Sequence[str] = (),
    *,
    fit: Sequence[str] = (),
    fix: Sequence[str] = (),
    height_correction: bool = False,
    report: Callable[[str], None] = to_stderr,
) -> CalibrationJob:
    """Calibrate ``setup`` from the frames at the known poses of ``poses`` (``known.csv``).

    Parameters
    ----------
    setup : Setup
    poses : str or Path
        ``known.csv``: image,x_mm,y_mm,z_mm[,dir_x,dir_y,dir_z].
    images : sequence of str
        The images of ``poses`` to use, in this order (default: all).
    fit, fix : sequence of str
        Parameter groups always fitted, never fitted (:data:`spotnav.pose.conefit.parameters.PARAMETER_GROUPS`).
    height_correction : bool
        Also fit the thesis method's ``instrument.height_correction`` (section 5.5).
    report : callable
        Takes each warning (a frame left out) as it comes (default: stderr).

    Raises
    ------
    SpotnavError
        For poses of a video's frames, an image not in ``poses``, or frames that cannot calibrate.
    """
    known = read_known_poses(poses)
    if any(pose.image == Path() for pose in known):
        raise SpotnavError(
            f"{poses} names a video's frames, not image files: calibrate reads images "
            "(render the known poses into a folder: render --path ... --out DIR)"
        )
    if images:
        by_path = {pose.image.resolve(): pose for pose in known}
        missing = [name for name in images if Path(name).resolve() not in by_path]
        if missing:
            raise SpotnavError(f"{missing[0]} is not in {poses}")
        known = [by_path[Path(name).resolve()] for name in images]
    frames = []
    ready(setup)
    for pose in progress(known, desc="calibrate", unit="image"):
        try:
            image = read_image(pose.image, expected_size=(setup.camera.width_px, setup.camera.height_px))
        except ImageReadError as error:
            report(f"spotnav: warning: {error}; left out")
            continue
        frames.append(KnownFrame(str(pose.image), image, pose.tip_in_eye, pose.axis))
    result = calibrate(frames, setup, fit=sorted(set(fit)), fix=sorted(set(fix)))
    for reason in result.skipped:
        report(f"spotnav: warning: {reason}; left out")
    lines = calibration_lines(result)
    calibrated = result.setup
    if height_correction:
        height = calibrate_height_correction(frames, calibrated)
        for reason in height.skipped:
            report(f"spotnav: warning: {reason}; left out of the height correction")
        lines.append(
            f"instrument.height_correction = {height.factor:.4f} (spread {height.spread:.4f}, "
            f"{height.frames} frames; the thesis method's section 5.5)"
        )
        calibrated = replace(calibrated, instrument=replace(calibrated.instrument, height_correction=height.factor))
    return CalibrationJob(calibrated, tuple(lines))


def calibration_lines(result: Calibration) -> list[str]:
    """What ``calibrate`` prints: the fitted values +- 1 sigma, what stayed at the setup's values and why, the
    residuals, its frames' tips and the held-out check."""
    lines = [f"frames used: {result.frames} ({result.points} edge points)", "fitted (value +- 1 sigma):"]
    for group, names in _by_group(result.fitted):
        ids = [GEOMETRY_PARAMETERS.index(name) for name in names]
        lines.append(f"  {_label(group, names)} = {_with_sigmas(result, ids)}{_key(result, group)}")
    exact = [name for name, reason in result.fixed if result.sigmas[GEOMETRY_PARAMETERS.index(name)] == 0]
    others = [(name, reason) for name, reason in result.fixed if name not in exact]
    if others:
        lines.append("left at the setup's values (their uncertainty stays in every pose's sigma_mm):")
    for name, reason in others:
        index = GEOMETRY_PARAMETERS.index(name)
        lines.append(f"  {name} = {_with_sigmas(result, [index])}: {reason}")
    if exact:
        lines.append(f"known exactly ([uncertainty] 0): {', '.join(exact)}")
    lines.append(
        f"RMS angle of the edge points from their cones: {result.rms_before_deg:.4f} deg before, "
        f"{result.rms_after_deg:.4f} deg after ({result.rms_after_px:.3f} px)"
    )
    edge = result.setup.calibration.frame_edge_sigma_deg
    lines.append(f"one frame's edge strays from the model by {edge:.4f} deg (1 sigma, each frame left out in turn)")
    misses, settled = np.array(result.tip_misses_mm), f"{len(result.tip_misses_mm)} of {result.frames} frames"
    if len(misses) < 2:
        lines.append(f"the frames' tips, found from their edges alone: not checked ({settled} settled)")
    else:
        covered = (
            "within what the covariance says"
            if result.covariance_scale == 1.0
            else f"more than the covariance said: its sigmas are scaled by {result.covariance_scale:.2f}"
        )
        lines.append(
            f"the frames' tips, found from their edges alone ({settled}): mean miss {misses.mean():.4f} mm, "
            f"max {misses.max():.4f} mm, {covered}"
        )
    lines.extend(_held_out_lines(result))
    if result.responses:
        tried = ", ".join(f"{r} {spread:.4f}" for r, spread in result.responses if np.isfinite(spread))
        response = result.setup.camera.response
        if response is None:
            lines.append(
                f"camera.response is not stated and the edges do not tell it from sRGB (spots' RMS offset, px: "
                f"{tried}): the frames are read as sRGB; state it if the camera writes linear or gamma values"
            )
        else:
            lines.append(
                f"camera.response = {response}: estimated, its spots agree best with the edge model "
                f"(spots' RMS offset, px: {tried}); written to the calibrated setup"
            )
    band = result.setup.instrument.edge_band_deg
    if result.edge_bands:
        tried = ", ".join(f"{b:.3f} {spread:.4f}" for b, spread in result.edge_bands if np.isfinite(spread))
        margin = f"{100 * EDGE_BAND_MARGIN:.0f} %"
        how = "fitted" if band != result.edge_bands[0][0] else f"the setup's (no other agrees {margin} better)"
        lines.append(
            f"instrument.edge_band_deg = {band:.4g}: the light's soft band about the edge, {how}, from the spots "
            f"that clip (spots' RMS offset, px, by band in deg: {tried})"
        )
    else:
        lines.append(
            f"instrument.edge_band_deg = {band:.4g}: the light's soft band, the setup's, written so that frames are "
            "read as these were (not fitted: no known frame's spot was read from its flank, where the band tells)"
        )
    return lines + _aperture_lines(result)


# What each group's values are in the written setup, where the name alone does not say.
_WRITTEN_AS = {
    "edge-angle": "instrument.edge_half_angle_deg",
    "light-radius": "instrument.light_radius_mm",
    "eye-radius": "eye.radius_mm",
    "camera-rotation": "a turn of camera.rotation",
    "camera-position": "the camera's centre in the eye frame, camera.translation_mm",
    "focal-length": "a change of camera.matrix's fx, fy",
    "principal-point": "camera.matrix's cx, cy",
    "distortion": "camera.distortion",
    "insertion-point": "instrument.insertion_point_mm",
    "beam-tilt": "instrument.beam_tilt_deg",
}


def _by_group(names: Sequence[str]) -> list[tuple[str, list[str]]]:
    """The parameter names by group, in :data:`~spotnav.pose.conefit.parameters.PARAMETER_GROUPS`' order."""
    groups = [(group, [GEOMETRY_PARAMETERS[i] for i in ids]) for group, ids in PARAMETER_GROUPS.items()]
    return [
        (group, [name for name in members if name in names]) for group, members in groups if set(members) & set(names)
    ]


def _label(group: str, names: Sequence[str]) -> str:
    """A group and, of several parameters, which: ``camera-rotation x, y``."""
    if len(PARAMETER_GROUPS[group]) == 1:
        return group
    parts = [name.rsplit("_", 1)[0] if unit_of(name) else name for name in names]  # less the unit
    return f"{group} {', '.join(part.rsplit('_', 1)[-1] for part in parts)}"


def _with_sigmas(result: Calibration, ids: Sequence[int]) -> str:
    """Parameters' values +- 1 sigma with their unit, each value to its sigma's second digit."""
    values, sigmas = result.values[list(ids)], result.sigmas[list(ids)]
    finite = sigmas[sigmas > 0]
    digits = int(np.clip(1 - np.floor(np.log10(finite.min())), 0, 6)) if len(finite) else 6
    shown = f"{', '.join(f'{v:.{digits}f}' for v in values)} +- {', '.join(f'{v:.2g}' for v in sigmas)}"
    unit = unit_of(GEOMETRY_PARAMETERS[ids[0]])
    return f"{shown} {unit}" if unit else shown


def _key(result: Calibration, group: str) -> str:
    """Where a fitted group is written (the focal length with the pixels it now is, the insertion point from
    known axes with how well they meet)."""
    written = _WRITTEN_AS.get(group)
    if group == "focal-length":
        written = f"{written}: {result.setup.camera.focal_px:.1f} px"
    if group == "insertion-point" and np.isfinite(result.insertion_rms_mm):
        written = f"{written}: where the known axes meet, RMS {result.insertion_rms_mm:.4f} mm"
    return f" ({written})" if written else ""


def _held_out_lines(result: Calibration) -> list[str]:
    """The held-out check, and a line that says the calibration misses when it does, with what to try."""
    held = result.held_out
    if held is None:
        return ["held-out check: not made (too few frames to calibrate without a quarter of them)"]
    answered = held.answered
    refused = [status for status in held.statuses if status != "ok"]
    line = (
        f"held-out check ({held.folds}-fold: each known frame localized, precise method, by a calibration of the "
        f"others; the setup written is the one of all {len(held.statuses)}): {answered} of {len(held.statuses)} ok"
    )
    if refused:
        line += f" ({', '.join(f'{refused.count(s)} {s}' for s in sorted(set(refused)))})"
    if answered:
        errors, sigmas = np.array(held.errors_mm), held.sigmas()
        line += (
            f", error mean {np.nanmean(errors):.4f} mm, max {np.nanmax(errors):.4f} mm, "
            f"{100 * held.coverage():.0f} % within 3 sigma (3-D), worst {sigmas.max():.1f} sigma"
        )
    lines = [line]
    if held.misses():
        lines.append(
            "the calibration MISSES its held-out frames: its sigmas do not hold on frames it has not seen; "
            "try more known frames spread over the working volume (x, y and height), with their axes, and check "
            "known.csv (tips in the eye frame, images in its order)"
        )
    return lines


def _aperture_lines(result: Calibration) -> list[str]:
    """What the calibration says of the lens's depth of field (``camera.aperture_mm``)."""
    camera = result.setup.camera
    if camera.aperture_mm is not None and not result.apertures:
        return [f"camera.aperture_mm = {camera.aperture_mm:.4g}: the lens's, as the setup states it (not fitted)"]
    if not result.apertures:
        return [
            "camera.aperture_mm: not stated, read as a pinhole (not fitted: no known frame's spot clips, where a "
            "blur of the light moves the edge)"
        ]
    tried = ", ".join(f"{a:.3g} {spread:.4f}" for a, spread in result.apertures if np.isfinite(spread))
    if camera.aperture_mm is None:
        margin = f"{100 * APERTURE_MARGIN:.0f} %"
        return [
            f"camera.aperture_mm: not stated; the spots that clip show no blur of the light (no aperture agrees "
            f"{margin} better than a pinhole; spots' RMS offset, px, by aperture in mm: {tried}): read as a pinhole"
        ]
    sigma = result.setup.calibration.aperture_sigma_mm
    return [
        f"camera.aperture_mm = {camera.aperture_mm:.4g} +- {sigma:.2g}: the lens's depth of field, fitted (the setup "
        f"states none) from the spots that clip, whose light it blurs (spots' RMS offset, px, by aperture in mm: "
        f"{tried}); written to the calibrated setup"
    ]
