"""Summarise a sweep: error per design point, and plots of error against cone angle and against power."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa

from spotnav.experiments.chapter6 import markdown_table
from spotnav.experiments.figures import plot_error_against
from spotnav.experiments.sweep import SWEEP_PARAMETERS, read_sweep_table

__all__ = ["SUMMARY_COLUMNS", "error_curves", "summary_rows", "varied_parameters", "write_sweep_report"]

SUMMARY_COLUMNS = ("frames", "ok", "availability", "mean_mm", "max_mm", "localize_ms")
_ANGLE, _BEAMS, _POWER = "instrument.beam_half_angle_deg", "instrument.beam_count", "light.power_w"


def _columns(table: pa.Table, names: Sequence[str]) -> list[np.ndarray]:
    return [table[name].to_numpy(zero_copy_only=False) for name in names]


def _statistics(errors: np.ndarray, statuses: np.ndarray, localize_ms: np.ndarray) -> list[float]:
    """``SUMMARY_COLUMNS`` over a group of rows; error statistics over its ``ok`` rows (NaN without any)."""
    ok = statuses == "ok"
    mean, worst = (float(f(errors[ok])) if ok.any() else float("nan") for f in (np.mean, np.max))
    return [len(errors), int(ok.sum()), float(ok.mean()), mean, worst, float(np.median(localize_ms))]


def varied_parameters(table: pa.Table) -> list[str]:
    """The sweep parameters that take more than one value in ``table``."""
    return [name for name in SWEEP_PARAMETERS if len(np.unique(table[name].to_numpy())) > 1]


def summary_rows(table: pa.Table) -> tuple[list[str], list[list[object]]]:
    """One row per design point, path and method: the varied parameters, then ``SUMMARY_COLUMNS``."""
    varied = varied_parameters(table)
    points, paths, methods, statuses, errors, localize_ms = _columns(
        table, ["point", "path", "method", "status", "error_mm", "localize_ms"]
    )
    parameters = _columns(table, varied)
    rows = []
    for key in dict.fromkeys(zip(points, paths, methods, strict=True)):
        chosen = (points == key[0]) & (paths == key[1]) & (methods == key[2])
        first = int(np.argmax(chosen))
        values = [p[first] for p in parameters]
        rows.append([*values, key[1], key[2], *_statistics(errors[chosen], statuses[chosen], localize_ms[chosen])])
    return [*varied, "path", "method", *SUMMARY_COLUMNS], rows


def error_curves(table: pa.Table, x_name: str) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Mean and max error of the ``ok`` rows against parameter ``x_name``, per beam count and method.

    Rows that differ in other parameters are pooled. Returns label -> (x, mean_mm, max_mm).
    """
    x, beams, methods, statuses, errors = _columns(table, [x_name, _BEAMS, "method", "status", "error_mm"])
    ok = statuses == "ok"
    curves = {}
    for beam_count, method in dict.fromkeys(zip(beams, methods, strict=True)):
        chosen = ok & (beams == beam_count) & (methods == method)
        values = np.unique(x[chosen])
        if len(values):
            label = f"{int(beam_count)} beam{'s' if beam_count > 1 else ''}, {method}"
            mean = np.array([errors[chosen & (x == v)].mean() for v in values])
            worst = np.array([errors[chosen & (x == v)].max() for v in values])
            curves[label] = (values, mean, worst)
    return curves


def write_sweep_report(directory: Path | str) -> str:
    """Write ``summary.csv``, ``summary.md`` and the two plots into a sweep's folder; return the summary.

    Raises
    ------
    spotnav.experiments.sweep.SweepError
        If the folder holds no sweep results.
    """
    directory = Path(directory)
    table = read_sweep_table(directory)
    header, rows = summary_rows(table)
    with (directory / "summary.csv").open("w", newline="") as handle:
        csv.writer(handle, lineterminator="\n").writerows([header, *rows])
    plots = (
        ("error_vs_cone_angle.png", _ANGLE, "cone half-angle beta [deg]", False),
        ("error_vs_power.png", _POWER, "light power [W]", True),
    )
    for name, column, xlabel, log_x in plots:
        title = f"Tip error against {xlabel.split(' [')[0]} (ok frames; other parameters pooled)"
        plot_error_against(directory / name, error_curves(table, column), xlabel, title, log_x=log_x)
    statuses = table["status"].to_numpy(zero_copy_only=False)
    text = "\n".join(
        [
            f"# Sweep: {table.num_rows} localizations, {int(np.sum(statuses == 'ok'))} ok",
            "",
            *markdown_table(header, [[_format(v) for v in row] for row in rows]),
            "",
            "![error against cone angle](error_vs_cone_angle.png)",
            "",
            "![error against power](error_vs_power.png)",
            "",
        ]
    )
    (directory / "summary.md").write_text(text)
    return text


def _format(value: object) -> str:
    if isinstance(value, float | np.floating):
        return f"{value:.4g}"
    return str(value)
