"""Summarise a sweep: error and statuses per design point, and a plot of the error and the frames' statuses
against each parameter it swept."""

from __future__ import annotations

import csv
from collections import Counter
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa

from spotnav.app.figures import plot_error_against
from spotnav.app.status_style import status_counts
from spotnav.experiments.report import markdown_table
from spotnav.experiments.sweep import read_sweep_table
from spotnav.experiments.sweep_file import SWEEP_PARAMETERS

__all__ = [
    "PARAMETER_LABELS",
    "SUMMARY_COLUMNS",
    "availability_curves",
    "error_curves",
    "plot_name",
    "refusal_rows",
    "summary_rows",
    "varied_parameters",
    "write_sweep_report",
]

SUMMARY_COLUMNS = ("frames", "ok", "availability", "refused", "mean_mm", "max_mm", "localize_ms")
_BEAMS = "instrument.beam_count"  # one curve per beam count: never an x axis
# Axis labels and file names of the parameters; any other is named by its key.
PARAMETER_LABELS = {
    "size_px": ("image size [px]", "size"),
    "instrument.beam_half_angle_deg": ("cone half-angle beta [deg]", "cone_angle"),
    "instrument.beam_tilt_deg": ("beam tilt [deg]", "beam_tilt"),
    "light.power_w": ("light power [W]", "power"),
    "light.blend": ("blend of the beam's edge", "blend"),
    "render.full_well_e": ("full well [electrons]", "full_well"),
    "render.read_noise_e": ("read noise [electrons]", "read_noise"),
    "render.exposure_stops": ("exposure [stops]", "exposure"),
    "eye.radius_mm": ("assumed eye radius [mm]", "eye_radius"),
    "world.eye_radius_mm": ("true eye radius [mm]", "true_eye_radius"),
}
_NOT_KEPT = "(not kept: written by a spotnav without the detail column)"
_LOG_RANGE = 20.0  # positive values spanning more than this factor are plotted on a log axis


def _columns(table: pa.Table, names: Sequence[str]) -> list[np.ndarray]:
    return [table[name].to_numpy(zero_copy_only=False) for name in names]


def _statistics(errors: np.ndarray, statuses: np.ndarray, localize_ms: np.ndarray) -> list[object]:
    """``SUMMARY_COLUMNS`` over a group of rows; error statistics over its ``ok`` rows (NaN without any).

    ``refused`` counts the other statuses (``"2 mismatch, 1 no_spot"``, ``none``).
    """
    ok = statuses == "ok"
    mean, worst = (float(f(errors[ok])) if ok.any() else float("nan") for f in (np.mean, np.max))
    refused = status_counts(Counter(statuses[~ok].tolist()), "none")
    return [len(errors), int(ok.sum()), float(ok.mean()), refused, mean, worst, float(np.median(localize_ms))]


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


def _curves(table: pa.Table, x_name: str) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
    """Per beam count and method, in the table's order: its label (``"3 beams, precise"``), the values of
    ``x_name`` and which rows are its."""
    x, beams, methods = _columns(table, [x_name, _BEAMS, "method"])
    for beam_count, method in dict.fromkeys(zip(beams, methods, strict=True)):
        label = f"{int(beam_count)} beam{'s' if beam_count > 1 else ''}, {method}"
        yield label, x, (beams == beam_count) & (methods == method)


def error_curves(table: pa.Table, x_name: str) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Mean and max error of the ``ok`` rows against parameter ``x_name``, per beam count and method.

    Rows that differ in other parameters are pooled. Returns label -> (x, mean_mm, max_mm); a curve without
    ``ok`` rows is left out (:func:`availability_curves` shows it).
    """
    statuses, errors = _columns(table, ["status", "error_mm"])
    curves = {}
    for label, x, rows in _curves(table, x_name):
        chosen = rows & (statuses == "ok")
        values = np.unique(x[chosen])
        if len(values):
            mean = np.array([errors[chosen & (x == v)].mean() for v in values])
            worst = np.array([errors[chosen & (x == v)].max() for v in values])
            curves[label] = (values, mean, worst)
    return curves


def availability_curves(table: pa.Table, x_name: str) -> dict[str, tuple[np.ndarray, dict[str, np.ndarray]]]:
    """The fraction of frames with each status against parameter ``x_name``, per beam count and method.

    Rows that differ in other parameters are pooled. Returns label -> (x, status -> fraction, each shape of x);
    the fractions at each x sum to 1.
    """
    (statuses,) = _columns(table, ["status"])
    curves = {}
    for label, x, rows in _curves(table, x_name):
        values = np.unique(x[rows])
        counts = {s: np.array([np.sum(rows & (x == v) & (statuses == s)) for v in values]) for s in set(statuses[rows])}
        frames = sum(counts.values())
        curves[label] = (values, {s: n / frames for s, n in sorted(counts.items())})
    return curves


def refusal_rows(table: pa.Table) -> list[list[object]]:
    """Per method and refusal status: its frames and its commonest ``detail`` (first line; a word if not kept)."""
    methods, statuses, details = _columns(table, ["method", "status", "detail"])
    rows: list[list[object]] = []
    for method, status in sorted(set(zip(methods, statuses, strict=True)) - {(m, "ok") for m in set(methods)}):
        chosen = (methods == method) & (statuses == status)
        common = Counter(_NOT_KEPT if d is None else d.split("\n")[0] for d in details[chosen]).most_common(1)[0][0]
        rows.append([method, status, int(chosen.sum()), common.replace("|", "/")])
    return rows


def write_sweep_report(directory: Path | str) -> str:
    """Write ``summary.csv``, ``summary.md`` and one plot per swept parameter into a sweep's folder.

    The plots are ``error_vs_<name>.png`` (:func:`plot_name`), against every
    parameter that took more than one value but the beam count (one curve per
    beam count and method), each with the frames' statuses beneath
    (:func:`availability_curves`). The summary counts the statuses per design
    point, path and method, and lists each refusal's commonest detail
    (:func:`refusal_rows`). Returns the summary's Markdown.

    Raises
    ------
    spotnav.experiments.sweep_file.SweepError
        If the folder holds no sweep results.
    """
    directory = Path(directory)
    table = read_sweep_table(directory)
    header, rows = summary_rows(table)
    with (directory / "summary.csv").open("w", newline="", encoding="utf-8") as handle:
        csv.writer(handle, lineterminator="\n").writerows([header, *rows])
    figures = []
    for column in varied_parameters(table):
        if column == _BEAMS:
            continue
        xlabel, _ = PARAMETER_LABELS.get(column, (column, ""))
        values = table[column].to_numpy().astype(float)
        log_x = bool(values.min() > 0 and values.max() > _LOG_RANGE * values.min())
        name = xlabel.split(" [")[0]
        title = f"Tip error (ok frames) and the frames' statuses against {name} (other parameters pooled)"
        curves, available = error_curves(table, column), availability_curves(table, column)
        plot_error_against(directory / plot_name(column), curves, available, xlabel, title, log_x=log_x)
        figures += [f"![error and statuses against {name}]({plot_name(column)})", ""]
    statuses = table["status"].to_numpy(zero_copy_only=False)
    refusals = refusal_rows(table)
    text = "\n".join(
        [
            f"# Sweep: {table.num_rows} localizations, {int(np.sum(statuses == 'ok'))} ok",
            "",
            f"Statuses: {status_counts(Counter(statuses.tolist()), 'none')}. Mean and max error over the ok frames.",
            "",
            *markdown_table(header, [[_format(v) for v in row] for row in rows]),
            "",
            *(
                [
                    "## Refusals",
                    "",
                    *markdown_table(
                        ["method", "status", "frames", "commonest detail"], [[_format(v) for v in r] for r in refusals]
                    ),
                    "",
                ]
                if refusals
                else []
            ),
            *(figures or ["No parameter took more than one value: nothing to plot against.", ""]),
        ]
    )
    (directory / "summary.md").write_text(text, encoding="utf-8")
    return text


def plot_name(parameter: str) -> str:
    """The file name of the plot against a sweep parameter: ``error_vs_power.png`` for ``light.power_w``."""
    short = PARAMETER_LABELS.get(parameter, ("", parameter.replace(".", "_")))[1]
    return f"error_vs_{short}.png"


def _format(value: object) -> str:
    if isinstance(value, float | np.floating):
        return f"{value:.4g}"
    return str(value)
