"""A design search's report: every candidate (``designs.csv``), the verified ones (``verified.csv``), the ranked
table beside the thesis's designs (``report.md``) and its plots."""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from spotnav.app.figures import plot_bound_against_error, plot_bound_over_workspace, plot_objective_against
from spotnav.experiments.design import DesignResult, DesignRun, Verification
from spotnav.experiments.design_file import DESIGN_PARAMETERS
from spotnav.experiments.report import markdown_table
from spotnav.experiments.sweep import parameter_values
from spotnav.experiments.sweep_report import PARAMETER_LABELS

__all__ = ["AGREEMENT", "DESIGN_COLUMNS", "VERIFIED_COLUMNS", "design_row", "write_design_report"]

AGREEMENT = 0.3  # the model fit's RMS should be within this share of the bound's
DESIGN_COLUMNS = (
    *("index", "label", "beams", "half_angle_deg", "tilt_deg", "power_w", "total_power_w", "blend", "size_px"),
    *("status", "detail", "objective_mm", "mean_mm", "p95_mm", "max_mm", "seconds"),
)
VERIFIED_COLUMNS = (
    *("index", "label", "poses", "fit_ok", "precise_ok", "precise_refused", "bound_rms_mm", "fit_rms_mm"),
    *("fit_over_bound", "fit_bias_mm", "precise_bound_rms_mm", "precise_rms_mm", "precise_over_bound", "seconds"),
)
_PLOTS = ("objective.png", "best_bound.png", "bound_vs_error.png")


def design_row(result: DesignResult) -> dict[str, Any]:
    """One row of ``designs.csv`` (:data:`DESIGN_COLUMNS`): a single beam's tilt is empty (it has none)."""
    values = parameter_values(result.setup)
    beams = result.setup.instrument.beam_count
    bounds = result.bounds_mm
    known = bounds[np.isfinite(bounds)]
    statistics = [float(f(known)) if len(known) else math.nan for f in (np.mean, _p95, np.max)]
    return dict(
        zip(
            DESIGN_COLUMNS,
            [
                result.candidate.index,
                result.candidate.label,
                beams,
                values["instrument.beam_half_angle_deg"],
                values["instrument.beam_tilt_deg"] if beams > 1 else "",
                values["light.power_w"],
                beams * values["light.power_w"],
                values["light.blend"],
                int(values["size_px"]),
                result.status,
                result.detail,
                result.objective_mm,
                *statistics,
                result.seconds,
            ],
            strict=True,
        )
    )


def _p95(values: np.ndarray) -> float:
    return float(np.percentile(values, 95))


def _verified_row(label: str, check: Verification) -> dict[str, Any]:
    fits, precise = np.isfinite(check.fit_errors_mm), np.isfinite(check.precise_errors_mm)
    return dict(
        zip(
            VERIFIED_COLUMNS,
            [
                check.index,
                label,
                len(check.bounds_mm),
                int(fits.sum()),
                int(precise.sum()),
                check.precise_refused,
                check.bound_rms_mm,
                check.fit_rms_mm,
                check.fit_rms_mm / check.bound_rms_mm,
                check.fit_bias_mm,
                check.precise_bound_rms_mm,
                check.precise_rms_mm,
                check.precise_rms_mm / check.precise_bound_rms_mm,
                check.seconds,
            ],
            strict=True,
        )
    )


def _write_csv(path: Path, columns: Sequence[str], rows: Sequence[dict[str, Any]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, columns, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)


def _format(value: object, digits: int = 3) -> str:
    if isinstance(value, float | np.floating):
        return "-" if not math.isfinite(value) else f"{value:.{digits}g}"
    return str(value)


def _design_text(row: dict[str, Any]) -> str:
    """``3 x 6.2 deg, tilt 15.1 deg, 0.50 W, blend 0.21, 512 px``."""
    tilt = f", tilt {float(row['tilt_deg']):.1f} deg" if row["tilt_deg"] != "" else ""
    return (
        f"{row['beams']} x {float(row['half_angle_deg']):.1f} deg{tilt}, "
        f"{float(row['power_w']):.2f} W, blend {float(row['blend']):.2f}, {row['size_px']} px"
    )


def _plots(directory: Path, run: DesignRun, rows: Sequence[dict[str, Any]]) -> list[str]:
    """Write the three plots; their Markdown lines."""
    search = run.search
    varied = [name for name, values in search.space if len(set(values)) > 1 and name != "instrument.beam_count"]
    columns = dict(
        zip(DESIGN_PARAMETERS, ("beams", "half_angle_deg", "tilt_deg", "power_w", "blend", "size_px"), strict=True)
    )
    beams = np.array([int(row["beams"]) for row in rows])
    objective = np.array([float(row["objective_mm"]) for row in rows])
    feasible = np.array([row["status"] == "feasible" for row in rows])
    panels = {}
    for name in varied:
        x = np.array([float(row[columns[name]]) if row[columns[name]] != "" else np.nan for row in rows])
        panels[PARAMETER_LABELS[name][0]] = (x, objective, feasible)
    title = f"Design search: {search.objective} of the tip's bound over the workspace (hollow: infeasible)"
    plot_objective_against(directory / _PLOTS[0], panels, beams, title)
    lines = [f"![objective against each parameter]({_PLOTS[0]})", ""]
    best = run.best
    if best is not None:
        title = f"Best design ({best.candidate.label}): the tip's bound over the workspace"
        plot_bound_over_workspace(directory / _PLOTS[1], search.workspace.tips(), best.bounds_mm, title)
        lines += [f"![the best design's bound over the workspace]({_PLOTS[1]})", ""]
    labels = {r.candidate.index: r.candidate.label for r in run.results}
    points = {
        labels[i]: (v.bound_rms_mm, v.fit_rms_mm, v.precise_bound_rms_mm, v.precise_rms_mm)
        for i, v in run.verifications.items()
    }
    if points:
        plot_bound_against_error(directory / _PLOTS[2], points, "Verified designs: simulated error against the bound")
        lines += [f"![simulated error against the bound]({_PLOTS[2]})", ""]
    return lines


def write_design_report(directory: Path | str, run: DesignRun) -> str:
    """Write ``designs.csv``, ``verified.csv``, ``report.md`` and the plots into ``directory``; return the report.

    The plots: ``objective.png`` (the objective against each varied parameter), ``best_bound.png`` (the best
    design's bound over the workspace) and ``bound_vs_error.png`` (each verified design's simulated error against
    its bound).
    """
    directory = Path(directory)
    search = run.search
    rows = [design_row(r) for r in run.results]
    by_index = {int(row["index"]): row for row in rows}
    _write_csv(directory / "designs.csv", DESIGN_COLUMNS, rows)
    verified = [_verified_row(str(by_index[i]["label"]), v) for i, v in run.verifications.items()]
    _write_csv(directory / "verified.csv", VERIFIED_COLUMNS, verified)
    checks = {int(row["index"]): row for row in verified}
    shown = [r for r in run.ranked if not r.candidate.reference][:10] + list(run.references)
    header = ["rank", "design", "parameters", "status", f"bound {search.objective} [mm]", "bound RMS [mm]"]
    header += ["model fit RMS [mm]", "fit / bound", "fit bias [mm]", "precise RMS [mm]", "precise / bound", "refused"]
    table = []
    for result in shown:
        row, check = by_index[result.candidate.index], checks.get(result.candidate.index)
        rank = run.ranked.index(result) + 1 if result in run.ranked else "-"
        verified_cells = ["-"] * 7
        if check is not None:
            keys = (
                "bound_rms_mm",
                "fit_rms_mm",
                "fit_over_bound",
                "fit_bias_mm",
                "precise_rms_mm",
                "precise_over_bound",
            )
            verified_cells = [_format(check[k]) for k in keys] + [str(check["precise_refused"])]
        status = result.status if result.feasible else f"{result.status}: {result.detail}"
        table.append([str(rank), result.candidate.label, _design_text(row), status, _format(result.objective_mm)])
        table[-1] += verified_cells
    statuses = [r.status for r in run.results if not r.candidate.reference]
    broken = ", ".join(f"{statuses.count(s)} {s}" for s in dict.fromkeys(statuses) if s != "feasible") or "none"
    limits = search.constraints
    workspace = search.workspace
    box = f" {list(workspace.min_mm)} to {list(workspace.max_mm)} mm" if workspace.kind == "box" else ""
    text = [
        f"# Design search: {len(statuses)} candidates, {statuses.count('feasible')} feasible",
        "",
        f"Objective: the {search.objective} over the workspace ({workspace.poses} poses, {workspace.kind}{box}, axis "
        f"through the insertion point) of the tip's Cramer-Rao bound from one frame. Constraints: all the beams' "
        f"light <= {limits.max_power_w:g} W, neighbouring cones > {limits.min_spot_gap_deg:g} deg apart, "
        f"spots on the fundus and in the image: {'required' if limits.on_fundus else 'not required'}. "
        f"Infeasible: {broken}.",
        "",
        f"Run: {run.wall_s:.1f} s {run.where} (bounds {run.search_s:.1f} s, verification {run.verify_s:.1f} s).",
        "",
        f"Verified: the first {search.verify_poses} workspace poses rendered and localized; the model fit (the "
        "efficient estimator, knowing the world) should come within "
        f"{AGREEMENT:.0%} of the bound's RMS, the precise method (spotnav's localizer) above it. 2 and 4 beams: "
        "model fit only, from the true tip displaced by 0.01 mm. 'fit bias': the length of the model fit's mean "
        "error (the bound holds unbiased estimates only); one frame a pose, so an unbiased fit's is about the bound's "
        "RMS over the root of the poses (0.3 times it for 12 poses): only a larger one is a bias. 'refused': frames "
        "the precise method refused.",
        "",
        *markdown_table(header, table),
        "",
        *_plots(directory, run, rows),
    ]
    report = "\n".join(text)
    (directory / "report.md").write_text(report, encoding="utf-8")
    return report
