"""The geometry study: frames rendered in a world that differs from the setup, before and after calibration.

Each case renders the helix in a world that differs from the nominal setup
(the thesis's) by one thing, or by everything at once: the insertion point,
the camera's height, position, tilt, focal length, principal point and lens,
the eye's radius, the beam's half-angle. Every frame is localized three ways
by the precise method: trusting the nominal geometry (a setup that states it
exactly: what spotnav did before it knew better), with the nominal setup as a
real user writes it (a real microscope's ``[uncertainty]``: sigma carries it,
or the frame is refused), and after ``spotnav calibrate`` on
:data:`~spotnav.experiments.calibration.KNOWN_FRAMES` frames at known poses
(tips and axes) rendered in the true world.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from spotnav.app.figures import plot_geometry_study
from spotnav.app.paths import path_poses
from spotnav.errors import SpotnavError
from spotnav.experiments.calibration import known_calibration
from spotnav.experiments.faults import SILENT_ERROR_MM, combine_changes, count_silent_failures
from spotnav.experiments.report import Experiment, Options, markdown_table, write_results_csv
from spotnav.experiments.runner import (
    ErrorSummary,
    FrameJob,
    FrameResult,
    Variant,
    count_refusals,
    error_cells,
    run_frame,
    summarize,
)
from spotnav.experiments.scenes import PATH_SEEDS, thesis_world
from spotnav.pose.conefit.parameters import PARAMETER_GROUPS, SHARED_SIZE, setup_with_geometry
from spotnav.setup.config import Setup
from spotnav.setup.sections import World
from spotnav.setup.uncertainty import Uncertainty

__all__ = [
    "GEOMETRY_CASES",
    "MAX_SIZE_PX",
    "GeometryCase",
    "change_beam",
    "change_camera",
    "change_eye_radius",
    "run_geometry",
    "shift_insertion",
]

MAX_SIZE_PX = 2048  # the study runs at the run's size up to this (the 2048 px)
CALIBRATION_FRAMES = 10
VARIANTS = ("trusting the nominal geometry", "nominal, as known", "after calibrate")


@dataclass(frozen=True)
class GeometryCase:
    """One way the true world differs from the nominal setup.

    Attributes
    ----------
    name : str
    change : callable
        Turns the nominal world (at the study's size) into the true one.
    beams : tuple of int
        The beam counts the case runs with.
    """

    name: str
    change: Callable[[Setup], Setup]
    beams: tuple[int, ...] = (1, 3)


def shift_insertion(*shift_mm: float) -> Callable[[Setup], Setup]:
    """A change that moves the insertion point by ``shift_mm`` (x, y, z), mm."""

    def change(world: Setup) -> Setup:
        x, y, z = world.instrument.insertion_in_eye + np.array(shift_mm)
        point = (float(x), float(y), float(z))
        return replace(world, instrument=replace(world.instrument, insertion_point_mm=point))

    return change


def change_camera(
    *,
    rotation_deg: float = 0.0,
    centre_mm: tuple[float, float, float] = (0.0, 0.0, 0.0),
    focal: float = 0.0,
    principal_px: float = 0.0,
    k1: float = 0.0,
) -> Callable[[Setup], Setup]:
    """A change of the camera: ``rotation_deg`` (about its y axis), ``centre_mm`` (x, y, z), ``focal``
    (relative), ``principal_px`` (u, at 2048 px; scaled to the size), ``k1``."""

    def change(world: Setup) -> Setup:
        shared = np.zeros(SHARED_SIZE)
        shared[PARAMETER_GROUPS["camera-rotation"][1]] = np.radians(rotation_deg)
        shared[list(PARAMETER_GROUPS["camera-position"])] = centre_mm
        shared[PARAMETER_GROUPS["focal-length"][0]] = focal
        shared[PARAMETER_GROUPS["principal-point"][0]] = principal_px * world.camera.width_px / 2048
        shared[PARAMETER_GROUPS["distortion"][0]] = k1
        camera = setup_with_geometry(world, shared).camera
        return replace(world, camera=camera)

    return change


def change_eye_radius(radius_mm: float) -> Callable[[Setup], Setup]:
    """A change that makes the true retina's radius ``radius_mm``, mm."""
    return lambda world: replace(world, world=World(eye_radius_mm=radius_mm))


def change_beam(half_angle_deg: float) -> Callable[[Setup], Setup]:
    """A change that makes the beams' half-angle ``half_angle_deg``, degrees."""
    return lambda world: replace(world, instrument=replace(world.instrument, beam_half_angle_deg=half_angle_deg))


GEOMETRY_CASES: tuple[GeometryCase, ...] = (
    GeometryCase("nothing", combine_changes()),
    GeometryCase("insertion point 0.5 mm in x", shift_insertion(0.5, 0.0, 0.0)),
    GeometryCase("insertion point 1 mm in z", shift_insertion(0.0, 0.0, 1.0)),
    GeometryCase("camera 1 mm higher (1 %)", change_camera(centre_mm=(0.0, 0.0, 1.0))),
    GeometryCase("focal length 1 % longer", change_camera(focal=0.01)),
    GeometryCase("eye radius 12.7 mm, setup 12.5", change_eye_radius(12.7)),
    GeometryCase("beam half-angle 9.3 deg, setup 9.0", change_beam(9.3)),
    GeometryCase("camera shifted 0.5 mm in x", change_camera(centre_mm=(0.5, 0.0, 0.0))),
    GeometryCase("camera tilted 0.5 deg", change_camera(rotation_deg=0.5)),
    GeometryCase("principal point 20 px off", change_camera(principal_px=20.0)),
    GeometryCase("radial distortion, k1 = -3", change_camera(k1=-3.0)),
    GeometryCase(
        "everything at once",
        combine_changes(
            shift_insertion(0.5, 0.0, 1.0),
            change_camera(centre_mm=(0.5, 0.0, 1.0), rotation_deg=0.5, focal=0.01, principal_px=20.0, k1=-3.0),
            change_eye_radius(12.7),
            change_beam(9.3),
        ),
    ),
)


def run_geometry(options: Options) -> Experiment:
    """The geometry study: every case of :data:`GEOMETRY_CASES`, one and three beams, on the helix."""
    size = min(options.size_px, MAX_SIZE_PX)
    header = ["case", "beams", "localized", "ok", "mean [mm]", "max [mm]", "within 3 sigma", "silent", "refusals"]
    rows: list[list[str]] = []
    cells: dict[tuple[str, int, str], ErrorSummary] = {}
    csv_rows: list[tuple[dict[str, object], FrameResult]] = []
    notes: list[str] = []
    summary: list[str] = []
    silent_total = {variant: 0 for variant in VARIANTS[1:]}
    for beams in (1, 3):
        nominal = replace(thesis_world(size, beams), uncertainty=Uncertainty())
        trusted = replace(nominal, uncertainty=Uncertainty.exact())
        for index, case in enumerate(GEOMETRY_CASES):
            if beams not in case.beams:
                continue
            world = case.change(thesis_world(size, beams))
            label = f"geometry: {case.name}, {beams} beam{'s' * (beams > 1)}"
            variants = [Variant(VARIANTS[0], trusted, "precise"), Variant(VARIANTS[1], nominal, "precise")]
            try:
                calibration = known_calibration(
                    options.runner, world, nominal, label, axes=True, count=CALIBRATION_FRAMES
                )
            except SpotnavError as error:
                notes.append(f"- {case.name}, {beams} beams: calibrate refused: {error}")
            else:
                variants.append(Variant(VARIANTS[2], calibration.setup, "precise"))
                fitted = ", ".join(name for name in calibration.fitted if not name.startswith("insertion"))
                notes.append(f"- {case.name}, {beams} beams: calibrate fitted {fitted}")
            poses = path_poses("helix", options.count, world.instrument.insertion_in_eye)
            jobs = [
                FrameJob(world, pose, PATH_SEEDS["helix"] + 1000 * index + i, tuple(variants))
                for i, pose in enumerate(poses)
            ]
            outputs = options.runner.map(run_frame, jobs, label)
            for number, variant in enumerate(variants):
                results = [output[number] for output in outputs]
                row, silent = _row(case.name, beams, variant.label, results)
                rows.append(row)
                if variant.label in silent_total:
                    silent_total[variant.label] += silent
                cells[(case.name, beams, variant.label)] = summarize(results)
                csv_rows += [
                    ({"case": case.name, "beams": beams, "variant": variant.label, "step": i}, r)
                    for i, r in enumerate(results)
                ]
        everything = cells.get(("everything at once", beams, VARIANTS[2]))
        if everything is not None:
            errors = f"mean {everything.mean_mm:.4f} mm, max {everything.max_mm:.4f} mm" if everything.ok else ""
            summary.append(
                f"{beams} beam{'s' * (beams > 1)} everything at once, calibrated: "
                f"{everything.ok}/{everything.frames} frames ok"
                + (f", {errors}" if errors else f" ({everything.refusals})")
            )
    write_results_csv(options.out / "geometry.csv", csv_rows)
    plot_geometry_study(options.out / "geometry.png", cells, [case.name for case in GEOMETRY_CASES], VARIANTS)
    lines = [
        "## Geometry: a world that is not the setup, before and after calibration",
        "",
        f"The helix ({options.count} poses, {size} px, 1 W) rendered in a world that differs from the nominal "
        "setup (the thesis's) as each row says, localized by the precise method three ways: trusting the "
        "nominal geometry (a setup that states it exactly), with the nominal setup as a user writes it "
        "(a real microscope's `[uncertainty]`: sigma carries it, or the frame is refused as `uncalibrated`), "
        f"and after `spotnav calibrate` on {CALIBRATION_FRAMES} frames at known tips and axes rendered in the "
        f"true world. A silent failure is a frame `ok` and over {SILENT_ERROR_MM} mm off; within 3 sigma "
        "counts the `ok` frames whose error is within 3 `sigma_mm`.",
        "",
        *markdown_table(header, rows),
        "",
        "![mean error and availability per case](geometry.png)",
        "",
        "What each calibration fitted (the rest it left at the nominal values, named in its output):",
        "",
        *notes,
    ]
    totals = "; ".join(f"{variant}: {count} silent failures" for variant, count in silent_total.items())
    return Experiment("geometry", "\n".join(lines), f"geometry: {totals}; " + "; ".join(summary))


def _row(case: str, beams: int, variant: str, results: list[FrameResult]) -> tuple[list[str], int]:
    summary = summarize(results)
    silent = count_silent_failures(results)
    row = [case, str(beams), variant, f"{summary.ok}/{summary.frames}", *error_cells(summary), str(silent)]
    row.append(count_refusals(results))
    return row, silent
