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
from spotnav.pose.known_frame import KnownFrame
from spotnav.setup.config import Setup
from spotnav.setup.uncertainty import GEOMETRY_PARAMETERS

__all__ = ["CalibrationJob", "calibration_lines", "run_calibration"]

_SETUP_KEYS = {
    "edge_half_angle_deg": "instrument.edge_half_angle_deg",
    "light_radius_mm": "instrument.light_radius_mm",
    "eye_radius_mm": "eye.radius_mm",
}


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
    """What ``calibrate`` prints: the fitted values +- 1 sigma, what stayed fixed and why, the residuals."""
    lines = [f"frames used: {result.frames} ({result.points} edge points)", "fitted (1 sigma):"]
    for name in result.fitted:
        index = GEOMETRY_PARAMETERS.index(name)
        lines.append(f"  {_SETUP_KEYS.get(name, name)} = {result.values[index]:.6g} +- {result.sigmas[index]:.2g}")
    if np.isfinite(result.insertion_rms_mm):
        lines.append(f"  (the insertion point is where the known axes meet, RMS {result.insertion_rms_mm:.4f} mm)")
    exact = [name for name, reason in result.fixed if result.sigmas[GEOMETRY_PARAMETERS.index(name)] == 0]
    others = [(name, reason) for name, reason in result.fixed if name not in exact]
    if others:
        lines.append("left at the setup's values (1 sigma):")
    for name, reason in others:
        index = GEOMETRY_PARAMETERS.index(name)
        lines.append(f"  {name} = {result.values[index]:.6g} +- {result.sigmas[index]:.2g}: {reason}")
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
