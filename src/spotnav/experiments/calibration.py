"""Calibration experiments: a wrong eye radius and an unknown beam edge, before and after calibrating.

Part A (section 6.8's world, true radius 13.5 mm, assumed 12.5 mm): the precise
method as it is, after ``spotnav calibrate --fit-radius`` on 8 frames at known
poses, and after self-calibrating the radius over the helix's own frames
(``localize --fit-radius``). Part B (a beam whose true edge is softer than the
setup's default model, blend 0.3): the precise method with the default edge
model, with the true one, and after ``spotnav calibrate`` on 8 known frames.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from spotnav.app.calibrate import calibrate
from spotnav.app.paths import path_poses
from spotnav.experiments.frame import render_timed
from spotnav.experiments.report import Experiment, Options, markdown_table, write_results_csv
from spotnav.experiments.runner import (
    FrameJob,
    FrameResult,
    FrameRunner,
    Variant,
    error_cells,
    localize_variants,
    render_frame,
    run_frame,
    summarize,
)
from spotnav.experiments.scenes import BEAMS, PATH_SEEDS, thesis_world, with_true_edge, with_uncertainty
from spotnav.optics.render import Renderer
from spotnav.pose.calibration import Calibration
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.known_frame import KnownFrame
from spotnav.pose.precise import EdgeFrame
from spotnav.pose.self_calibration import prepare_self_calibration, self_calibrate_radius
from spotnav.setup.config import Setup
from spotnav.setup.geometry import edge_angle_of_blend
from spotnav.setup.paths import poses_through_insertion, working_volume_tips
from spotnav.setup.sections import Instrument, Light, World
from spotnav.setup.uncertainty import GEOMETRY_PARAMETERS, Uncertainty

__all__ = ["KNOWN_FRAMES", "calibration_text", "held_out_text", "known_calibration", "run_calibration"]

KNOWN_FRAMES = 8
KNOWN_SEED = 20_000
SOFT_BLEND = 0.3


def known_calibration(
    runner: FrameRunner,
    world: Setup,
    localizer: Setup,
    label: str,
    *,
    fit: Sequence[str] = (),
    axes: bool = False,
    count: int = KNOWN_FRAMES,
) -> Calibration:
    """``spotnav calibrate`` on ``count`` frames at known tips drawn over the working volume, rendered in ``world``.

    ``axes``: the known poses carry the instrument's axis too (a robot knows it).
    """
    poses = poses_through_insertion(working_volume_tips(count, seed=42), world.instrument.insertion_in_eye)
    jobs = [FrameJob(world, pose, KNOWN_SEED + i, ()) for i, pose in enumerate(poses)]
    images = runner.map(render_frame, jobs, f"{label}: known frames")
    frames = [
        KnownFrame(f"known {i}", image, pose.tip_in_eye, pose.axis if axes else None)
        for i, (image, pose) in enumerate(zip(images, poses, strict=True))
    ]
    return calibrate(frames, localizer, fit=fit)


def calibration_text(result: Calibration, *names: str) -> str:
    """The named parameters' calibrated values +- 1 sigma, and its held-out check, for a report."""
    parts = []
    for name in names:
        index = GEOMETRY_PARAMETERS.index(name)
        parts.append(f"{name} {result.values[index]:.4f} +- {result.sigmas[index]:.4f}")
    return ", ".join([*parts, held_out_text(result)])


def held_out_text(result: Calibration) -> str:
    """The calibration's held-out check in a few words: its known frames localized by calibrations of the others."""
    held = result.held_out
    if held is None:
        return "held out: not checked"
    if not held.answered:
        return f"held out: 0/{len(held.statuses)} answered"
    errors = np.array(held.errors_mm)
    return (
        f"held out {held.answered}/{len(held.statuses)}: {np.nanmean(errors):.4f} / {np.nanmax(errors):.4f} mm, "
        f"{100 * held.coverage():.0f} % within 3 sigma{', MISSES' if held.misses() else ''}"
    )


def run_frame_with_edges(
    job: FrameJob,
) -> tuple[tuple[FrameResult, ...], tuple[PoseEstimate, EdgeFrame | None]]:
    """Worker: :func:`run_frame`'s results from one rendering, the first variant (precise) keeping its edges.

    The second item is that frame's share of the joint radius fit (:func:`prepare_self_calibration`).
    """
    image, render_ms = render_timed(Renderer(job.world), job.pose, job.seed)
    start = time.perf_counter()
    share = prepare_self_calibration(image, job.variants[0].setup)
    first = FrameResult(job.pose, share[0], render_ms, 1000 * (time.perf_counter() - start))
    return (first, *localize_variants(image, job, render_ms, job.variants[1:])), share


def _row(label: str, results: list[FrameResult], extra: str) -> list[str]:
    s = summarize(results)
    mean, worst, share = error_cells(s)
    return [label, mean, worst, f"{s.ok}/{s.frames}", share, extra]


def run_calibration(options: Options) -> Experiment:
    """Parts A and B (see the module's docstring), helix, 1 W, one and three beams."""
    runner, count = options.runner, options.count
    header = ["case", "mean [mm]", "max [mm]", "poses", "within 3 sigma", "fitted"]
    lines = [
        "## Calibration: a wrong eye radius and an unknown beam edge (precise method)",
        "",
        f"Helix, 1 W, {options.size_px} px, {count} poses. `calibrate` uses {KNOWN_FRAMES} frames at known tips "
        "(uniform over the working volume); the self-calibration fits one radius with all the helix's poses.",
        "",
        "### A: true radius 13.5 mm, assumed 12.5 mm (section 6.8)",
        "",
    ]
    csv_rows: list[tuple[dict[str, object], FrameResult]] = []
    summary = []
    for b, beams in BEAMS.items():
        world = thesis_world(options.size_px, beams, 1.0, World(eye_radius_mm=13.5))
        # The simulation knows its world but for the eye's radius, known as well as an eye is (0.25 mm).
        localizer = with_uncertainty(with_true_edge(world), eye_radius_mm=Uncertainty().eye_radius_mm)
        poses = path_poses("helix", count, world.instrument.insertion_in_eye)
        known = known_calibration(runner, world, localizer, f"radius, {b}", fit=["eye-radius"])
        calibrated = known.setup
        variants = (Variant("precise", localizer, "precise"), Variant("precise + calibrate", calibrated, "precise"))
        jobs = [FrameJob(world, pose, PATH_SEEDS["helix"] + i, variants) for i, pose in enumerate(poses)]
        outputs, shares = zip(*runner.map(run_frame_with_edges, jobs, f"radius, {b}"), strict=True)
        fitted = self_calibrate_radius(shares, localizer)
        self_results = [
            FrameResult(pose, estimate, out[0].render_ms, float("nan"))
            for pose, estimate, out in zip(poses, fitted.estimates, outputs, strict=True)
        ]
        cases = {
            "precise, assumes 12.5 mm": ([o[0] for o in outputs], "-"),
            "precise + calibrate --fit-radius": (
                [o[1] for o in outputs],
                calibration_text(known, "eye_radius_mm", "edge_half_angle_deg"),
            ),
            "precise + self-calibration": (
                self_results,
                f"radius {fitted.radius_mm:.3f} +- {fitted.radius_sigma_mm:.3f} mm ({fitted.frames} frames)",
            ),
        }
        lines += [f"{b}:", "", *markdown_table(header, [_row(k, r, x) for k, (r, x) in cases.items()]), ""]
        csv_rows += [
            ({"part": "radius", "beams": beams, "variant": k, "step": i}, r)
            for k, (results, _) in cases.items()
            for i, r in enumerate(results)
        ]
        s = summarize(self_results)
        worst = f"max error {s.max_mm:.4f} mm ({s.ok}/{s.frames} frames ok)" if s.ok else s.why_none
        summary.append(f"radius {b}: self-calibrated {fitted.radius_mm:.3f} mm (true 13.5), {worst}")
    true_edge = float(np.degrees(edge_angle_of_blend(np.radians(Instrument().beam_half_angle_deg), SOFT_BLEND)))
    lines += [
        f"### B: a softer beam (blend {SOFT_BLEND}, half-light angle {true_edge:.4f} deg) than the default model",
        "",
    ]
    for b, beams in BEAMS.items():
        world = replace(thesis_world(options.size_px, beams), light=Light(power_w=1.0, blend=SOFT_BLEND))
        # The simulation knows its world but for the beam's edge, known to the default's 0.3 deg.
        truth = with_true_edge(world)
        default = with_uncertainty(
            replace(truth, instrument=replace(truth.instrument, edge_half_angle_deg=None)),
            edge_half_angle_deg=Uncertainty().edge_half_angle_deg,
        )
        known = known_calibration(runner, world, default, f"edge, {b}")
        edge_variants = (
            Variant("precise, default edge model", default, "precise"),
            Variant("precise, true edge model", truth, "precise"),
            Variant("precise + calibrate", known.setup, "precise"),
        )
        poses = path_poses("helix", count, world.instrument.insertion_in_eye)
        jobs = [FrameJob(world, pose, PATH_SEEDS["helix"] + i, edge_variants) for i, pose in enumerate(poses)]
        edge_outputs = runner.map(run_frame, jobs, f"edge, {b}")
        fitted_edge = calibration_text(known, "edge_half_angle_deg")
        rows = [
            _row(v.label, [o[k] for o in edge_outputs], fitted_edge if k == 2 else "-")
            for k, v in enumerate(edge_variants)
        ]
        after, true = summarize([o[2] for o in edge_outputs]), summarize([o[1] for o in edge_outputs])
        ratio = after.mean_mm / true.mean_mm
        ratio_line = f"{ratio:.2f}" if np.isfinite(ratio) else f"- ({(after if not after.ok else true).why_none})"
        lines += [
            f"{b}:",
            "",
            *markdown_table(header, rows),
            "",
            f"Mean error after calibrating / with the true edge model: {ratio_line}.",
            "",
        ]
        csv_rows += [
            ({"part": "edge", "beams": beams, "variant": v.label, "step": i}, o[k])
            for k, v in enumerate(edge_variants)
            for i, o in enumerate(edge_outputs)
        ]
        summary.append(f"edge {b}: mean error after calibrating / with the true edge model {ratio_line}")
    write_results_csv(options.out / "calibration.csv", csv_rows)
    return Experiment("calibration", "\n".join(lines), "; ".join(summary))
