"""Figures in the style of the thesis's chapter 6 (PNG, matplotlib's Agg backend)."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Patch

from spotnav.app.status_style import status_style
from spotnav.pose.estimate import STATUSES

__all__ = [
    "plot_against_power",
    "plot_bound_against_error",
    "plot_bound_over_workspace",
    "plot_error_against",
    "plot_errors_by_status",
    "plot_fault_study",
    "plot_gallery",
    "plot_geometry_study",
    "plot_objective_against",
    "plot_path_3d",
    "plot_per_step",
    "plot_track_by_status",
]

_COLOURS = {"1 beam": "tab:green", "3 beams": "tab:blue"}


def _colour(label: str) -> str | None:
    """Colour by method when the label names one, else by beam count."""
    for key, colour in (("precise", "tab:purple"), ("5.5", "tab:orange"), ("thesis method", "tab:green")):
        if key in label:
            return colour
    return _COLOURS.get(label)


@contextmanager
def _figure(path: Path, rows: int, cols: int, size: tuple[float, float], title: str, **kw: Any) -> Iterator[np.ndarray]:
    figure, axes = plt.subplots(rows, cols, figsize=size, squeeze=False, **kw)
    try:
        yield axes
        figure.suptitle(title)
        figure.tight_layout()
        figure.savefig(path, dpi=110)
    finally:
        plt.close(figure)


def plot_path_3d(path: Path, truth_tips: np.ndarray, estimates: Mapping[str, np.ndarray], title: str) -> None:
    """True path as a line and estimated tips as dots, one 3D panel per estimate set (Figures 6.5, 6.6).

    Parameters
    ----------
    truth_tips : ndarray, shape (N, 3)
    estimates : mapping of label to ndarray, shape (N, 3)
        NaN rows (no pose) are left out.
    """
    cols = min(len(estimates), 2)
    rows = -(-len(estimates) // cols)
    with _figure(path, rows, cols, (5.5 * cols, 5 * rows), title, subplot_kw={"projection": "3d"}) as axes:
        for ax, (label, tips) in zip(axes.ravel(), estimates.items(), strict=True):
            ax.plot(*truth_tips.T, color="black", lw=1, label="true path")
            ax.scatter(*tips.T, s=8, color=_colour(label) or "tab:red", label="estimated")
            ax.set(title=label, xlabel="x [mm]", ylabel="y [mm]", zlabel="z [mm]")
            ax.legend(loc="upper left")


def plot_per_step(
    path: Path, panels: Mapping[str, Mapping[str, np.ndarray]], ylabel: str, title: str, *, log: bool = False
) -> None:
    """One panel per key of ``panels``, each with curves over the path's steps (Figures 6.7-6.9).

    Parameters
    ----------
    panels : mapping of panel title to (mapping of curve label to ndarray, shape (N,))
    log : bool
        Logarithmic y axis (for errors that span decades between methods).
    """
    with _figure(path, len(panels), 1, (10, 2.8 * len(panels)), title) as axes:
        for ax, (name, curves) in zip(axes[:, 0], panels.items(), strict=True):
            for label, values in curves.items():
                ax.plot(np.arange(len(values)), values, ".-", lw=0.8, ms=3, label=label, color=_colour(label))
            if log:
                ax.set_yscale("log")
            else:
                ax.axhline(0.0, color="grey", lw=0.6)
            ax.set(title=name, xlabel="step", ylabel=ylabel)
            ax.legend(fontsize="small")


def plot_against_power(
    path: Path, powers_w: Sequence[float], panels: Mapping[str, Mapping[str, Sequence[float]]], ylabel: str, title: str
) -> None:
    """Error against the light's power, one panel per path (Figures 6.17, 6.18).

    Curve labels read ``"<beams>, <variant>"``: the colour follows the beams, the
    line style the variant (dash-dot: the thesis's method, dashed: with its
    calibration, solid: the precise method, dotted: the thesis's printed numbers).
    """
    styles = {"printed": (":", "x"), "5.5": ("--", "s"), "precise": ("-", "^"), "thesis method": ("-.", "o")}
    with _figure(path, 1, len(panels), (6.5 * len(panels), 4.5), title) as axes:
        for ax, (name, curves) in zip(axes[0], panels.items(), strict=True):
            for label, values in curves.items():
                style, marker = next((v for k, v in styles.items() if k in label), ("-", "o"))
                colour = _COLOURS.get(label.split(",")[0])
                ax.plot(powers_w, values, linestyle=style, marker=marker, color=colour, label=label)
            ax.set(title=name, xscale="log", yscale="log", xlabel="power [W]", ylabel=ylabel)
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize="small")


def plot_gallery(path: Path, images: Mapping[str, np.ndarray], title: str) -> None:
    """Images side by side with their titles (Figure 6.16)."""
    with _figure(path, 1, len(images), (2.2 * len(images), 2.6), title) as axes:
        for ax, (label, image) in zip(axes[0], images.items(), strict=True):
            ax.imshow(image)
            ax.set_title(label, fontsize="small")
            ax.axis("off")


def _status_order(statuses: Sequence[str]) -> list[str]:
    """The statuses present, in the order of :data:`~spotnav.pose.estimate.STATUSES` (unknown ones last)."""
    return sorted(set(statuses), key=lambda s: (STATUSES.index(s) if s in STATUSES else len(STATUSES), s))


def plot_errors_by_status(
    path: Path, images: Sequence[str], errors_mm: np.ndarray, statuses: Sequence[str], title: str
) -> None:
    """Tip error per frame: ``ok`` frames as bars; every other status's frames as its own marker on the axis.

    Each status has its own colour and marker (:mod:`spotnav.app.status_style`); the legend gives the count of each.
    """
    index = np.arange(len(images))
    with _figure(path, 1, 1, (max(6.0, 0.12 * len(images) + 3) + 2, 4), title) as axes:
        ax = axes[0, 0]
        for status in _status_order(statuses):
            chosen = np.array([s == status for s in statuses])
            style = status_style(status)
            label = f"{status} ({chosen.sum()})"
            if status == "ok":
                ax.bar(index[chosen], errors_mm[chosen], color=style.colour, label=label)
            else:
                ax.plot(index[chosen], np.zeros(chosen.sum()), linestyle="none", marker=style.marker, ms=8,
                        color=style.colour, markeredgecolor="black", markeredgewidth=0.5, clip_on=False,
                        label=label)  # fmt: skip
        ax.set(xlabel="frame (poses.csv order)", ylabel="tip error [mm]")
        if len(images) <= 40:
            ax.set_xticks(index, images, rotation=90, fontsize="x-small")
        handles, labels = ax.get_legend_handles_labels()
        order = np.argsort([not label.startswith("ok ") for label in labels], kind="stable")  # ok's bars first
        ax.legend([handles[i] for i in order], [labels[i] for i in order], fontsize="small", title="status (frames)",
                  title_fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))  # fmt: skip


def plot_track_by_status(
    path: Path, truth_tips: np.ndarray, estimated_tips: np.ndarray, statuses: Sequence[str], title: str
) -> None:
    """The true path as a line, the ``ok`` frames' estimated tips as dots and every other frame as its status's
    marker at its true tip, in 3D (colours and markers of :mod:`spotnav.app.status_style`).

    Parameters
    ----------
    truth_tips, estimated_tips : ndarray, shape (N, 3)
        Eye frame, mm; the estimates are NaN without a pose.
    statuses : sequence of str, length N
    """
    with _figure(path, 1, 1, (9.0, 5.5), title, subplot_kw={"projection": "3d"}) as axes:
        ax = axes[0, 0]
        ax.plot(*truth_tips.T, color="black", lw=1, label="true path")
        for status in _status_order(statuses):
            chosen = np.array([s == status for s in statuses])
            style = status_style(status)
            tips = estimated_tips[chosen] if status == "ok" else truth_tips[chosen]
            where = "" if status == "ok" else ", at the true tip"
            ax.scatter(*tips.T, s=10 if status == "ok" else 30, marker=style.marker, color=style.colour,
                       edgecolors="none" if status == "ok" else "black", linewidths=0.4, depthshade=False,
                       label=f"{status} ({chosen.sum()}){where}")  # fmt: skip
        ax.set(xlabel="x [mm]", ylabel="y [mm]", zlabel="z [mm]")
        ax.legend(loc="upper left", bbox_to_anchor=(1.08, 1.0), fontsize="small")


def plot_error_against(
    path: Path,
    curves: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
    availability: Mapping[str, tuple[np.ndarray, Mapping[str, np.ndarray]]],
    xlabel: str,
    title: str,
    *,
    log_x: bool,
) -> None:
    """Mean (solid) and max (dotted) tip error against one parameter, one colour per curve; below it, one panel per
    curve of the frames' statuses against the parameter (stacked bars: ``ok`` at the bottom, then each refusal in its
    status's colour, one bar per value of the parameter), so that a curve with few or no ``ok`` frames is seen beside
    its error.

    Parameters
    ----------
    curves : mapping of label to (x, mean_mm, max_mm), each shape (N,)
    availability : mapping of label to (x, mapping of status to the fraction of frames with it), shapes (M,)
    log_x : bool
        Logarithmic x axis of the error (for power).
    """
    panels = max(len(availability), 1)
    with _figure(path, 2, panels, (max(9.5, 3.4 * panels), 8.5), title, height_ratios=(3, 2)) as axes:
        figure, grid = axes[0, 0].figure, axes[0, 0].get_gridspec()
        for ax in axes[0]:
            ax.remove()
        ax = figure.add_subplot(grid[0, :])
        for number, (label, (x, mean, worst)) in enumerate(curves.items()):
            ax.plot(x, mean, "o-", color=f"C{number}", label=f"{label}, mean")
            ax.plot(x, worst, "v:", color=f"C{number}", label=f"{label}, max")
        ax.set(xlabel=xlabel, ylabel="tip error of ok frames [mm]", yscale="log", xscale="log" if log_x else "linear")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
        shown: dict[str, Patch] = {}
        for ax, (label, (x, fractions)) in zip(axes[1], availability.items(), strict=False):
            bottom, place = np.zeros(len(x)), np.arange(len(x))  # one bar per value: a design point's, or pooled
            for status in [s for s in STATUSES if s in fractions] + [s for s in fractions if s not in STATUSES]:
                style = status_style(status)
                ax.bar(place, fractions[status], 0.7, bottom, color=style.colour)
                shown.setdefault(status, Patch(color=style.colour, label=status))
                bottom += fractions[status]
            step = -(-len(x) // 8)  # at most 8 labels
            ax.set_xticks(place[::step], [f"{v:.3g}" for v in x[::step]])
            ax.set(xlabel=xlabel, ylim=(0, 1))
            ax.set_title(label, fontsize="small")
        axes[1, 0].set_ylabel("fraction of frames")
        legend = {"fontsize": "x-small", "loc": "upper left", "bbox_to_anchor": (1.01, 1.0), "title": "status"}
        axes[1, -1].legend(handles=list(shown.values()), **legend)


def plot_fault_study(
    path: Path, cells: Mapping[tuple[str, str, str], tuple[float, int, bool]], silent_error_mm: float
) -> None:
    """Availability per disturbance and severity, one bar per method, silent failures written beside it.

    Parameters
    ----------
    cells : mapping of (category, severity, method) to (availability, silent failures, default severity)
    """
    cases = list(dict.fromkeys((category, severity) for category, severity, _ in cells))
    methods = list(dict.fromkeys(method for _, _, method in cells))
    height = 0.8 / len(methods)
    with _figure(path, 1, 1, (9, 0.32 * len(cases) * len(methods) + 1.5), "Availability under disturbances") as axes:
        ax = axes[0, 0]
        for number, method in enumerate(methods):
            y = np.arange(len(cases)) + number * height
            values = [cells[(*case, method)] for case in cases]
            ax.barh(y, [v[0] for v in values], height, color=_colour(method) or f"C{number}", label=method)
            for row, (_, silent, _) in zip(y, values, strict=True):
                if silent:
                    ax.text(1.01, row, f"{silent} silent", va="center", color="tab:red", fontsize="x-small")
        labels = [f"{c}: {s}" + (" (default)" if cells[(c, s, methods[0])][2] else "") for c, s in cases]
        ax.set_yticks(np.arange(len(cases)) + 0.4 - height / 2, labels, fontsize="x-small")
        ax.invert_yaxis()
        ax.set(xlim=(0, 1.2), xlabel=f"fraction of frames ok (silent: ok but over {silent_error_mm} mm off)")
        ax.legend(fontsize="small", loc="lower right")


def plot_geometry_study(
    path: Path, cells: Mapping[tuple[str, int, str], Any], cases: Sequence[str], variants: Sequence[str]
) -> None:
    """Mean tip error per case (log scale), one bar per variant, the frames ``ok`` written beside each bar.

    Parameters
    ----------
    cells : mapping of (case, beams, variant) to an ErrorSummary
    cases, variants : sequence of str
        In the order shown.
    """
    beams = sorted({b for _, b, _ in cells})
    height = 0.8 / len(variants)
    colours = ("tab:red", "tab:gray", "tab:blue")
    title = "A world that is not the setup: mean tip error, frames ok"
    with _figure(path, 1, len(beams), (7 * len(beams), 0.45 * len(cases) * len(variants) + 1.5), title) as axes:
        for ax, count in zip(axes[0], beams, strict=True):
            for number, variant in enumerate(variants):
                y = np.arange(len(cases)) + number * height
                summaries = [cells.get((case, count, variant)) for case in cases]
                means = [s.mean_mm if s is not None and s.ok else np.nan for s in summaries]
                ax.barh(y, means, height, color=colours[number % len(colours)], label=variant)
                for row, s, mean in zip(y, summaries, means, strict=True):
                    if s is not None:
                        where = mean if np.isfinite(mean) else 2e-4
                        ax.text(where * 1.1, row, f"{s.ok}/{s.frames}", va="center", fontsize="x-small")
            ax.set_xscale("log")
            ax.set_yticks(np.arange(len(cases)) + 0.4 - height / 2, cases, fontsize="x-small")
            ax.invert_yaxis()
            ax.set(xlim=(2e-4, 3.0), xlabel="mean tip error of the ok frames [mm]", title=f"{count} beam(s)")
            ax.legend(fontsize="x-small", loc="lower right")


def plot_objective_against(
    path: Path, panels: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]], beams: np.ndarray, title: str
) -> None:
    """A design search's objective against each parameter it varied, one panel each, one colour per beam count.

    Parameters
    ----------
    panels : mapping of x label to (x, objective_mm, feasible), each shape (N,)
        Infeasible designs with a bound are drawn hollow; those without none.
    beams : ndarray of int, shape (N,)
    """
    with _figure(path, 1, max(len(panels), 1), (3.6 * max(len(panels), 1), 3.8), title, sharey=True) as axes:
        for ax, (xlabel, (x, objective, feasible)) in zip(axes[0], panels.items(), strict=False):
            for number, count in enumerate(np.unique(beams)):
                chosen = (beams == count) & np.isfinite(objective)
                label = f"{count} beam{'s' if count > 1 else ''}"
                ax.scatter(x[chosen & feasible], objective[chosen & feasible], s=22, color=f"C{number}", label=label)
                ax.scatter(x[chosen & ~feasible], objective[chosen & ~feasible], s=22, facecolors="none",
                           edgecolors=f"C{number}")  # fmt: skip
            ax.set(xlabel=xlabel, yscale="log")
            ax.grid(True, which="both", alpha=0.3)
        axes[0, 0].set_ylabel("objective: tip bound [mm]")
        axes[0, 0].legend(fontsize="small")


def plot_bound_over_workspace(path: Path, tips: np.ndarray, bounds_mm: np.ndarray, title: str) -> None:
    """The tip's bound at each workspace tip: seen from above (x, y) and against the height z, mm."""
    with _figure(path, 1, 2, (10.0, 4.2), title) as axes:
        dots = axes[0, 0].scatter(tips[:, 0], tips[:, 1], c=bounds_mm, s=30, cmap="viridis")
        axes[0, 0].set(xlabel="x [mm]", ylabel="y [mm]", aspect="equal")
        plt.colorbar(dots, ax=axes[0, 0], label="tip bound [mm]")
        axes[0, 1].scatter(tips[:, 2], bounds_mm, s=20)
        axes[0, 1].set(xlabel="tip height z [mm]", ylabel="tip bound [mm]")
        axes[0, 1].grid(True, alpha=0.3)


def plot_bound_against_error(
    path: Path, rows: Mapping[str, tuple[float, float, float, float]], title: str, *, band: float = 0.3
) -> None:
    """Each verified design's RMS tip error against its bound's RMS: the model fit and the precise method.

    Parameters
    ----------
    rows : mapping of label to (bound_rms_mm, fit_rms_mm, precise_bound_rms_mm, precise_rms_mm)
    band : float
        The shaded agreement, +- this share about error = bound.
    """
    with _figure(path, 1, 1, (8.5, 5.0), title) as axes:
        ax = axes[0, 0]
        values = np.array([v for row in rows.values() for v in row], dtype=float)
        values = values[np.isfinite(values) & (values > 0)]
        if len(values):
            line = np.geomspace(values.min() / 2, values.max() * 2, 50)
            ax.plot(line, line, "k-", lw=0.8, label="error = bound")
            ax.fill_between(line, line * (1 - band), line * (1 + band), color="0.85", label=f"+-{band:.0%}")
        for number, (label, (bound, fit, precise_bound, precise)) in enumerate(rows.items()):
            ax.scatter([bound], [fit], marker="o", color=f"C{number}", label=f"{label}: model fit")
            ax.scatter([precise_bound], [precise], marker="s", facecolors="none", edgecolors=f"C{number}",
                       label=f"{label}: precise")  # fmt: skip
        ax.set(xlabel="bound, RMS over the poses [mm]", ylabel="simulated tip error, RMS [mm]")
        ax.set(xscale="log", yscale="log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize="x-small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
