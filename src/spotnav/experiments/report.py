"""What an experiment gets and gives back, and the report's shared formats: Markdown tables and the CSV of
every localized frame.

Every study is a function of :class:`Options` (output folder, image size, poses per path, the frame runner) that
writes its CSVs and figures into the output folder and returns an :class:`Experiment`: its section of
``report.md``, one line for the console and its :class:`Headline` rows for the report's summary table
(:mod:`spotnav.experiments.summary`). A figure that could not be measured (NaN: no frame gave a pose) is written
as :func:`number_text` writes it, ``-`` with the reason, never ``nan``.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spotnav.experiments.runner import FrameResult, FrameRunner

__all__ = ["Experiment", "Headline", "Options", "markdown_table", "number_text", "write_results_csv"]


@dataclass(frozen=True)
class Options:
    """What every experiment gets: output folder, image size, poses per path and the runner."""

    out: Path
    size_px: int
    count: int
    runner: FrameRunner


@dataclass(frozen=True)
class Headline:
    """One row of the report's summary table: a figure the thesis prints beside spotnav's.

    Attributes
    ----------
    figure : str
        What is measured, with the thesis's table.
    thesis : str
        The thesis's printed figure.
    plain, precise : str
        spotnav's figure by the thesis's method and by the precise method (``n/a ...`` where one does not apply).
    verdict : str
        How spotnav's figure compares, in words.
    section : str
        The heading (without its ``#``) of the report's section that holds the full table.
    """

    figure: str
    thesis: str
    plain: str
    precise: str
    verdict: str
    section: str


@dataclass(frozen=True)
class Experiment:
    """A finished experiment: a Markdown section, one line for the console and its rows of the summary table."""

    name: str
    markdown: str
    summary: str
    headlines: tuple[Headline, ...] = ()


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """A Markdown table of ``header`` and ``rows`` (cells as given), one line a row."""
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def number_text(value: float, spec: str, why: str) -> str:
    """``value`` as ``spec`` formats it, or ``- (why)`` where it is not a finite number (nothing was measured)."""
    return format(value, spec) if np.isfinite(value) else f"- ({why})"


def write_results_csv(path: Path, rows: Sequence[tuple[dict[str, object], FrameResult]]) -> None:
    """Every pose: its labels, truth, estimate, errors per axis, rotation errors and timings."""
    columns = ["true_x", "true_y", "true_z", "true_dir_x", "true_dir_y", "true_dir_z", "status", "spots"]
    columns += ["x_mm", "y_mm", "z_mm", "dir_x", "dir_y", "dir_z", "error_mm", "error_x", "error_y", "error_z"]
    columns += ["rot_error_y_deg", "rot_error_z_deg", "axis_error_deg", "sigma_mm", "rms_px"]
    columns += ["render_ms", "localize_ms", "detail"]
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        labels = list(rows[0][0]) if rows else []
        writer.writerow(labels + columns)
        for tags, r in rows:
            estimate = r.estimate
            tip = estimate.tip_in_eye if estimate.tip_in_eye is not None else np.full(3, np.nan)
            axis = estimate.axis if estimate.axis is not None else np.full(3, np.nan)
            numbers = [*r.truth.tip_in_eye, *r.truth.axis]
            tail = [*tip, *axis, r.error_mm, *r.error_xyz_mm, *r.rotation_error_deg, estimate.sigma_mm, estimate.rms_px]
            writer.writerow(
                [*tags.values(), *(f"{v:.6f}" for v in numbers), estimate.status, estimate.spots]
                + [("" if not np.isfinite(v) else f"{v:.6f}") for v in tail]
                + [f"{r.render_ms:.1f}", f"{r.localize_ms:.1f}", estimate.detail]
            )
