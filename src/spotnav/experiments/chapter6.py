"""The thesis's chapter 6 study: the paths, the light power and a deformed or larger eye, beside its numbers.

Sections 6.4-6.6 and 6.9 (:func:`run_paths`): the square and the helix at every power, one and three beams, in
two exposures; sections 6.7 and 6.8 (:func:`run_world`): the helix in a world the localizer does not model.
Every frame is rendered in :func:`~spotnav.experiments.scenes.thesis_world` and localized three ways: with the
thesis's method as written, with section 5.5's height correction (fitted on one frame at a known pose of the
same world) and with the precise method. The ellipse tests of sections 6.2-6.3 are
:mod:`spotnav.experiments.ellipse`.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TypeVar

import numpy as np

from spotnav.app.figures import plot_against_power, plot_gallery, plot_path_3d, plot_per_step
from spotnav.app.paths import path_poses
from spotnav.app.status_style import status_counts
from spotnav.experiments.bounds import bound_rows, path_bounds
from spotnav.experiments.gallery import power_gallery, saturating_exposure_stops
from spotnav.experiments.report import Experiment, Headline, Options, markdown_table, write_results_csv
from spotnav.experiments.runner import (
    ErrorSummary,
    FrameJob,
    FrameResult,
    FrameRunner,
    Variant,
    calibrate_height,
    run_frame,
    summarize,
)
from spotnav.experiments.scenes import BEAMS, PATH_SEEDS, bump_grid, thesis_world, with_true_edge
from spotnav.experiments.summary import error_headline, pair_text
from spotnav.pose.bound import PoseBound
from spotnav.setup.config import Setup
from spotnav.setup.examples import THESIS_EXPOSURE_STOPS
from spotnav.setup.geometry import InstrumentPose
from spotnav.setup.paths import HELIX, SQUARE_CORNERS_MM
from spotnav.setup.sections import Instrument, World

__all__ = [
    "EXPOSURES",
    "POWERS_W",
    "THESIS",
    "run_paths",
    "run_world",
]

POWERS_W = (0.01, 0.1, 0.25, 0.5, 1.0, 1.5, 2.0)
CALIBRATION_TIP_MM = (0.0, 0.0, 4.5)
CALIBRATION_SEED = 99_999
PLAIN, CALIBRATED, PRECISE = "thesis method", "thesis + 5.5", "precise"
VARIANTS = (PLAIN, CALIBRATED, PRECISE)

# The thesis's numbers: (mean, max) in mm, or rotation errors in degrees.
THESIS: dict[str, dict[str, tuple[float, float]]] = {
    "square": {"1 beam": (0.026, 0.100), "3 beams": (0.023, 0.074)},  # Table 6.9
    "helix": {"1 beam": (0.031, 0.133), "3 beams": (0.026, 0.080)},  # Table 6.11
    "bumps": {"1 beam": (0.035, 0.210), "3 beams": (0.027, 0.080)},  # Table 6.17
    "radius": {"1 beam": (0.151, 0.566), "3 beams": (0.144, 0.566)},  # Table 6.18
    # Tables 6.10 and 6.12: (about y, about z) as (mean, max) pairs.
    "square rotation y": {"1 beam": (0.053, 0.285), "3 beams": (0.044, 0.224)},
    "square rotation z": {"1 beam": (0.100, 0.355), "3 beams": (0.072, 0.258)},
    "helix rotation y": {"1 beam": (0.070, 0.436), "3 beams": (0.058, 0.263)},
    "helix rotation z": {"1 beam": (0.089, 0.230), "3 beams": (0.077, 0.036)},
}
THESIS_POWER = {  # Tables 6.13-6.16: power -> (mean, max)
    ("square", "1 beam"): [(0.093, 0.263), (0.040, 0.153), (0.033, 0.121), (0.029, 0.107), (0.026, 0.100),
                           (0.025, 0.097), (0.025, 0.088)],
    ("square", "3 beams"): [(0.086, 0.158), (0.037, 0.083), (0.029, 0.075), (0.025, 0.073), (0.023, 0.074),
                            (0.021, 0.073), (0.020, 0.072)],
    ("helix", "1 beam"): [(0.126, 0.603), (0.051, 0.242), (0.039, 0.167), (0.034, 0.152), (0.031, 0.133),
                          (0.029, 0.129), (0.028, 0.122)],
    ("helix", "3 beams"): [(0.109, 0.300), (0.044, 0.092), (0.033, 0.078), (0.029, 0.081), (0.026, 0.080),
                           (0.024, 0.083), (0.024, 0.086)],
}  # fmt: skip
EXPOSURES = {"default exposure": 0.0, "thesis's exposure": THESIS_EXPOSURE_STOPS}
EXPOSURE_SUFFIX = {"default exposure": "", "thesis's exposure": "_thesis_exposure"}  # figure names
THESIS_TABLE_NUMBERS = {"square": ("6.9", "6.10", "6.13", "6.14"), "helix": ("6.11", "6.12", "6.15", "6.16")}


# --- running configurations ------------------------------------------------------------------------------


_Key = TypeVar("_Key", bound=tuple[object, ...])  # a configuration's key: (beams,) or (beams, power)


def _run_configs(
    runner: FrameRunner, worlds: Mapping[_Key, Setup], poses: Sequence[InstrumentPose], seed: int, label: str
) -> tuple[dict[_Key, dict[str, list[FrameResult]]], dict[_Key, float]]:
    """Calibrate each world (section 5.5), then render and localize ``poses`` in it, plain and calibrated.

    Returns results by world key and variant label, and the fitted factors (NaN where the
    calibration frame showed no usable spot; then only the plain variant runs).
    """
    keys = list(worlds)
    calibration = [
        FrameJob(worlds[k], _calibration_pose(worlds[k]), CALIBRATION_SEED, (Variant("cal", worlds[k]),)) for k in keys
    ]
    factors = dict(zip(keys, runner.map(calibrate_height, calibration, f"{label}: calibrate"), strict=True))
    jobs, job_keys = [], []
    for key in keys:
        world = worlds[key]
        variants = [Variant(PLAIN, world, "thesis")]
        if np.isfinite(factors[key]):
            instrument = replace(world.instrument, height_correction=factors[key])
            variants.append(Variant(CALIBRATED, replace(world, instrument=instrument), "thesis"))
        variants.append(Variant(PRECISE, with_true_edge(world), "precise"))
        jobs += [FrameJob(worlds[key], pose, seed + i, tuple(variants)) for i, pose in enumerate(poses)]
        job_keys += [key] * len(poses)
    outputs = runner.map(run_frame, jobs, label)
    results: dict[_Key, dict[str, list[FrameResult]]] = {key: {} for key in keys}
    for key, job, frame_results in zip(job_keys, jobs, outputs, strict=True):
        for variant, result in zip(job.variants, frame_results, strict=True):
            results[key].setdefault(variant.label, []).append(result)
    return results, factors


def _calibration_pose(world: Setup) -> InstrumentPose:
    return InstrumentPose.through_insertion(np.array(CALIBRATION_TIP_MM), world.instrument.insertion_in_eye)


# --- formatting --------------------------------------------------------------------------------------------


def _cell(value: float, digits: int = 3) -> str:
    return "no pose" if not np.isfinite(value) else f"{value:.{digits}f}"


def _variant_summaries(results: Mapping[str, list[FrameResult]]) -> dict[str, ErrorSummary | None]:
    return {label: summarize(results[label]) if label in results else None for label in VARIANTS}


def _value(summary: ErrorSummary | None, pick: Callable[[ErrorSummary], float]) -> str:
    return "no calibration" if summary is None else _cell(pick(summary))


def _error_table(
    thesis_key: str,
    by_beams: Mapping[str, Mapping[str, list[FrameResult]]],
    bounds: Mapping[str, Sequence[PoseBound]] | None = None,
) -> list[str]:
    """Mean and max Euclidean error, the thesis's printed numbers beside each method (Tables 6.9, 6.11, 6.17, 6.18);
    with each pose's ``bounds`` by beams, each method's RMS error beside the bound's RMS over the same poses."""
    header = ["", *(f"{b}: {col}" for b in by_beams for col in ("thesis (printed)", *VARIANTS))]
    rows: list[list[str]] = [["mean error [mm]"], ["max error [mm]"], ["frames with a pose"]]
    for beams, results in by_beams.items():
        thesis = THESIS[thesis_key][beams]
        summaries = _variant_summaries(results)
        rows[0] += [f"{thesis[0]:.3f}", *(_value(s, lambda x: x.mean_mm) for s in summaries.values())]
        rows[1] += [f"{thesis[1]:.3f}", *(_value(s, lambda x: x.max_mm) for s in summaries.values())]
        rows[2] += ["100/100", *("-" if s is None else f"{s.ok}/{s.frames}" for s in summaries.values())]
    if bounds is not None:
        rows += bound_rows(by_beams, bounds, VARIANTS)
    return [*markdown_table(header, rows), "", *_uncertainty_lines(by_beams)]


def _uncertainty_lines(by_case: Mapping[str, Mapping[str, list[FrameResult]]]) -> list[str]:
    lines = []
    for case, results in by_case.items():
        s = summarize(results[PRECISE])
        lines.append(
            f"- precise, {case}: {s.within_3_sigma_text} of the errors within 3 sigma "
            f"(median 1-sigma {s.sigma_median_mm:.4f} mm)."
            if s.ok
            else f"- precise, {case}: {s.why_none}."
        )
    return lines


def _rotation_table(path: str, by_beams: Mapping[str, Mapping[str, list[FrameResult]]]) -> list[str]:
    """Rotation errors about y and z and the axis angle, mean and max (Tables 6.10, 6.12)."""
    methods = (PLAIN, PRECISE)
    header = [""]
    header += [f"about {a}: {m}" for a in "yz" for m in ("thesis (printed)", *methods)]
    header += [f"axis angle: {m}" for m in VARIANTS]
    rows = []
    for beams, results in by_beams.items():
        summaries = _variant_summaries(results)
        for index, name in ((0, "mean"), (1, "max")):
            row = [f"{name} [deg], {beams}"]
            for k, a in enumerate("yz"):
                row.append(f"{THESIS[f'{path} rotation {a}'][beams][index]:.3f}")
                row += [_rotation_cell(summaries[m], index, k) for m in methods]
            row += [_rotation_cell(summaries[m], index, 2) for m in VARIANTS]
            rows.append(row)
    return markdown_table(header, rows)


def _rotation_cell(summary: ErrorSummary | None, index: int, component: int) -> str:
    """Mean (``index`` 0) or max rotation error: about y, about z or the axis angle (``component`` 0, 1, 2)."""
    if summary is None:
        return "no calibration"
    return _cell((summary.rotation_mean_deg if index == 0 else summary.rotation_max_deg)[component])


def _tips(results: Sequence[FrameResult]) -> np.ndarray:
    return np.array([r.estimate.tip_in_eye if r.estimate.ok else np.full(3, np.nan) for r in results])


# --- 6.4-6.6 and 6.9: the paths and the power sweep ----------------------------------------------------------


def run_paths(options: Options) -> Experiment:
    """Sections 6.4-6.6 and 6.9: square and helix at every power, one and three beams, in both exposures."""
    out, size, count = options.out, options.size_px, options.count
    insertion = Instrument().insertion_in_eye
    insertion_text = ", ".join(f"{v:g}" for v in insertion)
    criterion = saturating_exposure_stops(size)
    lines = [
        "## Sections 6.4-6.6: square and helix paths, light power (Tables 6.7-6.16)",
        "",
        f"Table 6.8's setup (36 mm sensor, 300 mm lens, beta 9 deg) at {size} px; soft edge blend 0.15; "
        f"procedural retina; sensor noise; {count} poses per path, axis through the insertion point "
        f"({insertion_text}). Three beams tilt 15 deg from the axis. Section 5.5's factor is fitted on one frame "
        f"with the tip at {CALIBRATION_TIP_MM} mm in the same world (same power and beams). The precise method "
        "gets the simulated light's edge model (`instrument.edge_half_angle_deg`, 8.655 deg for blend 0.15) and "
        "constrains the axis through the insertion point; `sigma` is its reported 1-sigma tip uncertainty.",
        "",
        "Every experiment runs in two exposures:",
        "",
        "- **default exposure** (`render.exposure_stops = 0`, `spotnav scene --example`): the spot is not "
        "saturated, so the frame keeps the light across the cone's soft edge.",
        f"- **thesis's exposure** (`render.exposure_stops = {THESIS_EXPOSURE_STOPS:g}`, "
        "`spotnav scene --example thesis-exposure`): the spot is saturated from 1 W up, as in the thesis's "
        "Figure 6.16 (section 6.6: the first four images, 0.01-0.5 W, differ clearly in brightness, the rest "
        "only slightly in blurriness). Criterion: a spot stops brightening when it is white, full scale in every "
        "channel; the exposure is the one at which the spot at (0, 0, 8) mm, straight down, reaches full scale "
        f"at 1 W in the median of its centre's darkest channel: +{criterion:.2f} stops at this size, "
        f'rounded up to the half stop, +{THESIS_EXPOSURE_STOPS:g} (docs/methods.md, "The thesis\'s exposure").',
        "",
        "Table 6.7, the square (closed, P1-P2-P3-P4-P1):",
        "",
        *markdown_table(
            ["", "x", "y", "z"], [[f"P{i + 1}", *(f"{v:g}" for v in p)] for i, p in enumerate(SQUARE_CORNERS_MM)]
        ),
        "",
        "The helix (the thesis gives no parameters; thesis-notes 8): "
        + ", ".join(f"{k} = {v:g}" for k, v in HELIX.items())
        + ", about the z axis.",
        "",
    ]
    csv_rows: list[tuple[dict[str, object], FrameResult]] = []
    at_1w: dict[tuple[str, str], dict[str, dict[str, list[FrameResult]]]] = {}
    sections = []
    thesis_means: dict[str, dict[str, dict[str, list[float]]]] = {}
    for regime, stops in EXPOSURES.items():
        section, at_1w_regime, thesis_means[regime] = _run_regime(options, regime, stops, csv_rows)
        sections += section
        at_1w |= {(regime, path): by_beams for path, by_beams in at_1w_regime.items()}
    side_by_side, headlines = _side_by_side(at_1w)
    lines += [*side_by_side, "", *sections, *_gap_lines(at_1w, thesis_means)]
    write_results_csv(out / "paths.csv", csv_rows)
    summary = "; ".join(f"{regime}, {path}: {_summary_text(by_beams)}" for (regime, path), by_beams in at_1w.items())
    return Experiment("paths", "\n".join(lines), "at 1 W: " + summary, tuple(headlines))


def _run_regime(
    options: Options, regime: str, stops: float, csv_rows: list[tuple[dict[str, object], FrameResult]]
) -> tuple[list[str], dict[str, dict[str, dict[str, list[FrameResult]]]], dict[str, dict[str, list[float]]]]:
    """One exposure's paths at every power: its report section, the results at 1 W by path and beams, and the
    thesis method's mean error per power (by path, then beams), mm.

    Appends every frame's row to ``csv_rows``; figures go to ``options.out`` with the regime's suffix.
    """
    out, size = options.out, options.size_px
    suffix = EXPOSURE_SUFFIX[regime]
    insertion = Instrument().insertion_in_eye
    gallery = power_gallery(options, POWERS_W, stops)
    plot_gallery(
        out / f"power_gallery{suffix}.png",
        gallery,
        f"Spot at (0, 0, 8) mm, straight down, per power, {regime} (Figure 6.16)",
    )
    lines = [f"### {_regime_heading(regime)}", ""]
    power_curves: dict[str, dict[str, dict[str, list[float]]]] = {"mean": {}, "max": {}}
    at_1w = {}
    for path in ("square", "helix"):
        poses = path_poses(path, options.count, insertion)
        worlds = {
            (b, p): thesis_world(size, beams, p, exposure_stops=stops) for b, beams in BEAMS.items() for p in POWERS_W
        }
        results, factors = _run_configs(options.runner, worlds, poses, PATH_SEEDS[path], f"{path}, {regime}")
        for (b, p), by_variant in results.items():
            for label, frames in by_variant.items():
                tags = {"path": path, "beams": BEAMS[b], "power_w": p, "exposure_stops": stops, "variant": label}
                csv_rows += [({**tags, "step": i}, r) for i, r in enumerate(frames)]
        at_1w[path] = {b: results[(b, 1.0)] for b in BEAMS}
        t_err, t_rot, *t_power = THESIS_TABLE_NUMBERS[path]
        lines += [
            f"#### {path.capitalize()} path, 1 W, {regime}",
            "",
            f"Table {t_err}: Euclidean tip error; under it, "
            "each method's RMS error beside the Cramer-Rao bound's RMS over the same poses (section "
            "'Efficiency' splits the gap into bias and spread).",
            "",
        ]
        at_1w_worlds = {b: worlds[(b, 1.0)] for b in BEAMS}
        bounds = path_bounds(options.runner, at_1w_worlds, poses, f"{path}, {regime}: bound")
        lines += _error_table(path, at_1w[path], bounds)
        lines += ["", f"Table {t_rot}: rotation error of the axis (about y, about z; and the angle between axes).", ""]
        lines += _rotation_table(path, at_1w[path])
        lines += ["", *_statuses_lines(at_1w[path]), ""]
        _plot_path(out, path, poses, at_1w[path], f"{regime}", suffix)
        lines += [f"![{path}: path](path_{path}{suffix}.png)", f"![{path}: error per step](error_{path}{suffix}.png)"]
        lines += [f"![{path}: error per axis](error_xyz_{path}{suffix}.png)"]
        lines += [f"![{path}: rotation](rotation_{path}{suffix}.png)", ""]
        for b, table_number in zip(BEAMS, t_power, strict=True):
            lines += [f"Table {table_number}: {path}, {b}, error against power, {regime}.", ""]
            lines += _power_table(path, b, results, factors)
            lines += ["", *_statuses_lines({f"{p:g} W, {b}": results[(b, p)] for p in POWERS_W}), ""]
            for label in VARIANTS:
                summaries = [_variant_summaries(results[(b, p)])[label] for p in POWERS_W]
                for kind in ("mean", "max"):
                    values = [np.nan if s is None else (s.mean_mm if kind == "mean" else s.max_mm) for s in summaries]
                    power_curves[kind].setdefault(path, {})[f"{b}, {label}"] = values
            for kind, index in (("mean", 0), ("max", 1)):
                printed = [row[index] for row in THESIS_POWER[(path, b)]]
                power_curves[kind][path][f"{b}, thesis printed"] = printed
    for kind, number in (("mean", "6.17"), ("max", "6.18")):
        plot_against_power(
            out / f"power_{kind}{suffix}.png",
            POWERS_W,
            power_curves[kind],
            f"{kind} error [mm]",
            f"{kind.capitalize()} error against power, {regime} (Figure {number})",
        )
    lines += [
        f"![mean error against power, {regime}](power_mean{suffix}.png)",
        f"![max error against power, {regime}](power_max{suffix}.png)",
        f"![spot per power, {regime}](power_gallery{suffix}.png)",
        "",
    ]
    plain = {path: {b: curves[f"{b}, {PLAIN}"] for b in BEAMS} for path, curves in power_curves["mean"].items()}
    return lines, at_1w, plain


def _regime_heading(regime: str) -> str:
    return f"{regime.capitalize()} ({EXPOSURES[regime]:+g} stops)"


def _side_by_side(
    at_1w: Mapping[tuple[str, str], Mapping[str, Mapping[str, list[FrameResult]]]],
) -> tuple[list[str], list[Headline]]:
    """The thesis's printed mean and max at 1 W beside both exposures' (Tables 6.9 and 6.11), and the same as
    rows of the report's summary."""
    header = ["path, beams", "thesis (printed)"]
    header += [f"{regime}: {m}" for regime in EXPOSURES for m in (PLAIN, "ratio to printed", PRECISE)]
    rows, headlines = [], []
    for path in ("square", "helix"):
        for b in BEAMS:
            printed = THESIS[path][b]
            row = [f"{path}, {b}", f"{printed[0]:.3f} / {printed[1]:.3f}"]
            for regime in EXPOSURES:
                plain, precise = (summarize(at_1w[(regime, path)][b][m]) for m in (PLAIN, PRECISE))
                row += [pair_text(plain), plain.text(plain.mean_mm / printed[0], ".2f"), pair_text(precise, 4)]
                figure = f"Table {THESIS_TABLE_NUMBERS[path][0]}: {path}, {b}, {regime}"
                headlines.append(error_headline(figure, printed, plain, precise, _regime_heading(regime)))
            rows.append(row)
    return [
        "### Side by side at 1 W: mean / max tip error [mm]",
        "",
        *markdown_table(header, rows),
        "",
        "Where some frames gave no pose, a cell counts the frames `ok` and names the others' statuses. "
        "Where a spot is at full scale inside its edge, "
        "the half level is gone: its edge is read from the unclipped flank by the photometric model "
        "(docs/methods.md); only a beam without a soft band, blown out to a step, is refused (`unreliable`, "
        '"... at full scale in every channel").',
    ], headlines


def _gap_lines(
    at_1w: Mapping[tuple[str, str], Mapping[str, Mapping[str, list[FrameResult]]]],
    thesis_means: Mapping[str, Mapping[str, Mapping[str, Sequence[float]]]],
) -> list[str]:
    """Section 6.9, and why the thesis method's error differs from the printed one: the measured z bias per
    exposure, and how much its mean error falls from 0.5 to 2 W at the thesis's exposure against the thesis's."""
    bias = {
        regime: np.mean(
            [summarize(at_1w[(regime, path)][b][PLAIN]).bias_xyz_mm[2] for path in ("square", "helix") for b in BEAMS]
        )
        for regime in EXPOSURES
    }
    default, thesis = (f"{bias[r]:+.3f} mm" for r in EXPOSURES)
    ratio = [
        np.mean([summarize(at_1w[(r, p)][b][PLAIN]).mean_mm / THESIS[p][b][0] for p in PATH_SEEDS for b in BEAMS])
        for r in EXPOSURES
    ]
    explained = (
        "the soft edge alone does not explain the gap to the printed numbers, the exposure does most of it."
        if ratio[1] - 1.0 < 0.5 * (ratio[0] - 1.0)
        else "the exposure explains less than half of the gap."
    )
    half, full = POWERS_W.index(0.5), POWERS_W.index(2.0)

    def fall(curve: Sequence[float]) -> float:
        return 100.0 * (1.0 - curve[full] / curve[half])

    saturated = thesis_means[list(EXPOSURES)[1]]
    ours = float(np.nanmean([fall(saturated[path][b]) for path in saturated for b in BEAMS]))
    printed = float(np.mean([fall([row[0] for row in THESIS_POWER[key]]) for key in THESIS_POWER]))
    flattens = ours <= 1.5 * printed
    shape = (
        "so the power curve flattens as Tables 6.13-6.16's does."
        if flattens
        else "so with more light the edge keeps creeping outward through the blend's toe, where the thesis's curve "
        "flattens: the thesis's light may have had a narrower blend, a light of finite size or Blender's Filmic "
        "view transform, none of which it states."
    )
    lines = [
        "### Section 6.9: calibration, and the gap to the printed numbers",
        "",
        "The thesis found that its height factor did not help and left it out. At the default exposure the edge "
        "is soft and unsaturated, so the Otsu edge sits inside the cone, near the angle where the light is half "
        "of its full value; the spot looks small and the tip too low, and the factor removes most of that bias "
        "(compare the `thesis method` and `thesis + 5.5` columns). The precise method needs no such factor: its "
        "edge model puts the edge where the light is half of its full value.",
        "",
    ]
    if not np.all(np.isfinite([*bias.values(), *ratio, ours])):
        return [*lines, "No average of the gap: some path gave the thesis's method no pose at 0.5, 1 or 2 W."]
    return [
        *lines,
        f"At 1 W the thesis method's mean errors are {ratio[0]:.1f} times the printed ones at the default exposure "
        f"and {ratio[1]:.1f} times at the thesis's (both paths, both beam counts): {explained} A saturated spot's "
        "plateau is clipped, so Otsu's threshold lies at a small fraction of the light's unclipped value and the "
        "edge moves out toward the cone's 9 deg, where the thesis's method assumes it. "
        f"The thesis method's mean z bias at 1 W: {default} at the default "
        f"exposure, {thesis} at the thesis's. From 0.5 to 2 W the thesis method's mean error falls by {ours:.0f} % "
        f"at the thesis's exposure (both paths, both beam counts) and by {printed:.0f} % in Tables 6.13-6.16, " + shape,
    ]


def _statuses_lines(by_case: Mapping[str, Mapping[str, list[FrameResult]]]) -> list[str]:
    """One line per case and method whose frames did not all give a pose from every beam."""
    lines = []
    for case, results in by_case.items():
        beams = 3 if case.endswith("3 beams") else 1
        for method in (PLAIN, PRECISE):
            frames = results[method]
            partial = sum(1 for r in frames if r.estimate.ok and r.estimate.spots < beams)
            if partial or any(not r.estimate.ok for r in frames):
                statuses = status_counts(Counter(r.estimate.status for r in frames), "none")
                text = f"{statuses}; {partial} poses answered from fewer spots than beams"
                lines.append(f"- {case}, {method}: {text}.")
    return lines


def _power_table(
    path: str,
    beams: str,
    results: Mapping[tuple[str, float], Mapping[str, list[FrameResult]]],
    factors: Mapping[tuple[str, float], float],
) -> list[str]:
    header = ["power [W]", *(f"{k}: {m}" for k in ("mean", "max") for m in ("thesis (printed)", *VARIANTS))]
    header += [f"poses: {m}" for m in (PLAIN, PRECISE)] + ["factor 5.5"]
    rows = []
    for p, printed in zip(POWERS_W, THESIS_POWER[(path, beams)], strict=True):
        summaries = _variant_summaries(results[(beams, p)])
        row = [f"{p:g}"]
        for index, pick in ((0, lambda x: x.mean_mm), (1, lambda x: x.max_mm)):
            row += [f"{printed[index]:.3f}", *(_value(summaries[m], pick) for m in VARIANTS)]
        counts = [summaries[m] for m in (PLAIN, PRECISE)]
        row += [f"{c.ok}/{c.frames}" if c is not None else "-" for c in counts]
        factor = factors[(beams, p)]
        rows.append([*row, "failed" if not np.isfinite(factor) else f"{factor:.4f}"])
    return markdown_table(header, rows)


def _plot_path(
    out: Path,
    path: str,
    poses: Sequence[InstrumentPose],
    at_1w: Mapping[str, Mapping[str, list[FrameResult]]],
    regime: str,
    suffix: str,
) -> None:
    truth = np.array([p.tip_in_eye for p in poses])
    title = f"{path.capitalize()} path, 1 W, {regime}"
    cases = {f"{b}, {m}": at_1w[b][m] for b in BEAMS for m in (PLAIN, PRECISE)}
    plot_path_3d(out / f"path_{path}{suffix}.png", truth, {c: _tips(r) for c, r in cases.items()}, title)
    errors = {b: {m: np.array([r.error_mm for r in at_1w[b][m]]) for m in VARIANTS} for b in BEAMS}
    plot_per_step(out / f"error_{path}{suffix}.png", errors, "Euclidean error [mm]", title, log=True)
    xyz = {c: np.array([r.error_xyz_mm for r in frames]) for c, frames in cases.items()}
    panels = {c: {axis: values[:, k] for k, axis in enumerate("xyz")} for c, values in xyz.items()}
    plot_per_step(out / f"error_xyz_{path}{suffix}.png", panels, "error [mm]", f"{title}: error per axis")
    rotation = {c: np.array([r.rotation_error_deg for r in frames]) for c, frames in cases.items()}
    panels = {c: {"about y": v[:, 0], "about z": v[:, 1], "axis angle": v[:, 2]} for c, v in rotation.items()}
    plot_per_step(out / f"rotation_{path}{suffix}.png", panels, "error [deg]", f"{title}: rotation error")


# --- 6.7 and 6.8: a deformed and a larger eye ----------------------------------------------------------------


WORLDS: dict[str, Callable[[], World]] = {
    "bumps": lambda: World(bumps=bump_grid()),
    "radius": lambda: World(eye_radius_mm=13.5),
}
WORLD_FIGURES = {"bumps": "deformed retina", "radius": "eye radius 13.5 mm, assumed 12.5"}
WORLD_TEXT = {
    "bumps": (
        "Section 6.7: a deformed retina (Table 6.17)",
        "15 Gaussian bumps, radius 0.25 mm, height 0.1 mm toward the centre, in 3 rows (y = -2, 0, 2 mm) "
        "by 5 columns (x = -3, -1.5, 0, 1.5, 3 mm)",
    ),
    "radius": (
        "Section 6.8: a wrong eye radius (Table 6.18)",
        "the retina's true radius is 13.5 mm while the localizer assumes 12.5 mm (thesis-notes 7)",
    ),
}


def run_world(name: str, options: Options) -> Experiment:
    """Sections 6.7 (``bumps``) and 6.8 (``radius``): the helix in a world the localizer does not model."""
    insertion = Instrument().insertion_in_eye
    poses = path_poses("helix", options.count, insertion)
    worlds = {(b,): thesis_world(options.size_px, beams, 1.0, WORLDS[name]()) for b, beams in BEAMS.items()}
    results, factors = _run_configs(options.runner, worlds, poses, PATH_SEEDS["helix"], name)
    by_beams = {b: results[(b,)] for b in BEAMS}
    title, text = WORLD_TEXT[name]
    factor_text = ", ".join(f"{b} {factors[(b,)]:.4f}" for b in BEAMS)
    lines = [
        f"## {title}",
        "",
        f"Helix, 1 W, {options.size_px} px, {options.count} poses; {text}. The 5.5 factor is fitted in the same "
        f"world ({factor_text}).",
        "",
        *_error_table(name, by_beams),
        "",
        *_statuses_lines(by_beams),
    ]
    panels = {b: {m: np.array([r.error_mm for r in by_beams[b][m]]) for m in (PLAIN, PRECISE)} for b in BEAMS}
    plot_per_step(options.out / f"error_{name}.png", panels, "Euclidean error [mm]", title, log=True)
    lines += ["", f"![{name}: error per step](error_{name}.png)"]
    csv_rows = [
        ({"beams": BEAMS[b], "variant": label, "step": i}, r)
        for b in BEAMS
        for label, frames in by_beams[b].items()
        for i, r in enumerate(frames)
    ]
    write_results_csv(options.out / f"{name}.csv", csv_rows)
    table = "6.17" if name == "bumps" else "6.18"
    headlines = tuple(
        error_headline(
            f"Table {table}: {WORLD_FIGURES[name]}, helix, {b}",
            THESIS[name][b],
            summarize(by_beams[b][PLAIN]),
            summarize(by_beams[b][PRECISE]),
            title,
        )
        for b in BEAMS
    )
    return Experiment(name, "\n".join(lines), _summary_text(by_beams), headlines)


def _summary_text(by_beams: Mapping[str, Mapping[str, list[FrameResult]]]) -> str:
    """Mean/max error per beam count, thesis method and precise, for the console."""
    parts = []
    for b, results in by_beams.items():
        plain, precise = summarize(results[PLAIN]), summarize(results[PRECISE])
        parts.append(f"{b} thesis's method {_pair_ok(plain)}, precise {_pair_ok(precise)}")
    return "mean/max tip error [mm], frames ok: " + "; ".join(parts)


def _pair_ok(summary: ErrorSummary) -> str:
    """``0.0312/0.1330 (25/25 ok)``, or why no frame gave a pose."""
    if not summary.ok:
        return summary.why_none
    return f"{summary.mean_mm:.4f}/{summary.max_mm:.4f} ({summary.ok}/{summary.frames} ok)"
