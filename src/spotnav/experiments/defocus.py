"""The lens's defocus on clipped spots: a depth of field the setup states, does not state, or ``calibrate`` measures.

Each row renders the helix at +4.5 stops (every spot's plateau clipped) through a lens focused at the pole whose
depth of field blurs the light at the helix's spots by 0.5, 1 or 2 px (their median; :func:`with_lens_blur`), and
localizes it by the precise method with the world's setup stated exactly three ways: without the lens (``camera.
aperture_mm`` unstated, a pinhole), with it stated, and after ``spotnav calibrate`` on
:data:`~spotnav.experiments.calibration.KNOWN_FRAMES` frames at known tips and axes, from the nominal setup with a
real microscope's ``[uncertainty]`` and no aperture (the calibration fits it).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from spotnav.app.paths import path_poses
from spotnav.errors import SpotnavError
from spotnav.experiments.calibration import KNOWN_FRAMES, known_calibration
from spotnav.experiments.report import Experiment, Options, markdown_table
from spotnav.experiments.runner import FrameJob, FrameResult, Variant, count_refusals, run_frame, summarize
from spotnav.experiments.scenes import BEAMS, PATH_SEEDS, thesis_world, with_lens_blur, with_true_edge
from spotnav.pose.estimate import within_sigmas
from spotnav.setup.config import Setup
from spotnav.setup.uncertainty import Uncertainty

__all__ = ["DEFOCUS_BLURS_PX", "DEFOCUS_STOPS", "run_defocus"]

DEFOCUS_BLURS_PX = (0.5, 1.0, 2.0)
DEFOCUS_STOPS = 4.5
_SILENT_MM = 0.05
_SILENT_SIGMAS = 5.0


def _pinhole(setup: Setup) -> Setup:
    """The setup with no aperture stated."""
    return replace(setup, camera=replace(setup.camera, aperture_mm=None))


def _cells(results: list[FrameResult]) -> list[str]:
    """Answered, mean / max error, within 3 sigma (3-D) and silent (ok and over 0.05 mm or 5 sigma, 3-D)."""
    summary = summarize(results)
    ok = [r for r in results if r.estimate.ok]
    errors = np.array([r.error_mm for r in ok])
    sigmas = np.array([r.estimate.sigma_mm for r in ok])
    within = f"{100 * within_sigmas(errors, sigmas).mean():.0f} %" if ok else "-"
    silent = int(np.sum((errors > _SILENT_MM) | ~within_sigmas(errors, sigmas, _SILENT_SIGMAS))) if ok else 0
    mean_max = f"{summary.text(summary.mean_mm)} / {summary.text(summary.max_mm)}"
    return [f"{summary.ok}/{summary.frames}", mean_max, within, str(silent), count_refusals(results)]


def run_defocus(options: Options) -> Experiment:
    """The defocus study (see the module's docstring), one and three beams."""
    header = ["defocus", "beams", "setup", "answered", "mean / max [mm]", "within 3 sigma", "silent", "refusals"]
    rows, fitted = [], []
    for b, beams in BEAMS.items():
        for index, blur in enumerate(DEFOCUS_BLURS_PX):
            world = with_lens_blur(thesis_world(options.size_px, beams, exposure_stops=DEFOCUS_STOPS), blur)
            stated = with_true_edge(world)
            variants = [Variant("lens unstated", _pinhole(stated), "precise")]
            variants.append(Variant("lens stated", stated, "precise"))
            nominal = replace(_pinhole(thesis_world(options.size_px, beams)), uncertainty=Uncertainty())
            label = f"defocus {blur:g} px, {b}"
            try:
                calibration = known_calibration(options.runner, world, nominal, label, axes=True, count=KNOWN_FRAMES)
            except SpotnavError as error:
                fitted.append(f"{label}: calibrate refused: {error}")
            else:
                variants.append(Variant("calibrated", calibration.setup, "precise"))
                aperture = calibration.setup.camera.aperture_mm
                sigma = calibration.setup.calibration.aperture_sigma_mm
                fitted.append(
                    f"{label}: aperture {world.camera.aperture_mm:.3f} mm, calibrated "
                    + ("none" if aperture is None else f"{aperture:.3f} +- {sigma:.3f} mm")
                )
            poses = path_poses("helix", options.count, world.instrument.insertion_in_eye)
            seed = PATH_SEEDS["helix"] + 1000 * index
            jobs = [FrameJob(world, pose, seed + i, tuple(variants)) for i, pose in enumerate(poses)]
            outputs = options.runner.map(run_frame, jobs, label)
            for number, variant in enumerate(variants):
                rows.append([f"{blur:g} px", str(beams), variant.label, *_cells([o[number] for o in outputs])])
    lines = [
        "## Defocus: the lens's depth of field on clipped spots",
        "",
        f"The helix ({options.count} poses, {options.size_px} px, 1 W, +{DEFOCUS_STOPS:g} stops: every plateau "
        "clipped) through a lens focused at the pole whose depth of field blurs the light at the helix's spots by "
        "the row's blur (their median sigma). The precise method with the world's setup without the lens, with it "
        f"stated (`camera.aperture_mm`), and after `spotnav calibrate` on {KNOWN_FRAMES} frames at known tips and "
        "axes from the nominal setup (a real microscope's `[uncertainty]`, no aperture). Within 3 sigma in 3-D "
        f"(`within_sigmas`); silent: `ok` and over {_SILENT_MM} mm or {_SILENT_SIGMAS:g} sigma off.",
        "",
        *markdown_table(header, rows),
        "",
        *(f"- {line}" for line in fitted),
    ]
    return Experiment("defocus", "\n".join(lines), "; ".join(fitted))
