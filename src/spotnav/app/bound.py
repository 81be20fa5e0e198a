"""``spotnav analyze bound``: the Cramer-Rao bound of one pose or along a path, as text, a CSV and a plot."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from spotnav.app.figures import plot_per_step
from spotnav.app.progress import progress
from spotnav.pose.bound import PoseBound, pose_bound
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose
from spotnav.setup.sections import Faults

__all__ = ["BoundRun", "bound_text", "run_bound", "write_bound"]

_NO_FAULTS = Faults()
BOUND_COLUMNS = (
    *("step", "status", "tip_x_mm", "tip_y_mm", "tip_z_mm", "bound_x_mm", "bound_y_mm", "bound_z_mm"),
    *("bound_tip_mm", "bound_axis_deg", "pixels", "clipped_share"),
)


@dataclass(frozen=True)
class BoundRun:
    """The bound at each pose.

    Attributes
    ----------
    poses : tuple of InstrumentPose
    bounds : tuple of PoseBound
        One per pose.
    through_insertion : bool
        The localizer knows that the axis runs through the insertion point.
    ignored_faults : tuple of str
        The setup's ``[faults]`` that the model leaves out (all but ``defocus_px``).
    """

    poses: tuple[InstrumentPose, ...]
    bounds: tuple[PoseBound, ...]
    through_insertion: bool
    ignored_faults: tuple[str, ...] = ()

    def totals_mm(self) -> np.ndarray:
        """Each pose's total tip bound (NaN where there is none), shape (N,), mm."""
        return np.array([b.tip_mm if b.ok else np.nan for b in self.bounds])


def run_bound(setup: Setup, poses: Sequence[InstrumentPose], *, through_insertion: bool = True) -> BoundRun:
    """The bound of every pose of ``poses`` in ``setup``'s world (a progress bar past one pose)."""
    shown = progress(poses, desc="bound", unit="pose") if len(poses) > 1 else poses
    bounds = tuple(pose_bound(setup, pose, through_insertion=through_insertion) for pose in shown)
    ignored = tuple(
        f.name
        for f in fields(Faults)
        if f.name != "defocus_px" and getattr(setup.faults, f.name) != getattr(_NO_FAULTS, f.name)
    )
    return BoundRun(tuple(poses), bounds, through_insertion, ignored)


def _unknowns(run: BoundRun) -> str:
    """What the localizer is taken not to know besides the tip."""
    axis = "axis through the insertion point" if run.through_insertion else "axis unknown"
    roll = ", the beams' roll" if any("roll" in b.parameters for b in run.bounds) else ""
    return f"{axis}; the light's power{roll} unknown"


def bound_text(run: BoundRun) -> str:
    """The bound as the command prints it: one pose in full, or a path's table and summary."""
    lines = [f"Cramer-Rao bound of one frame ({_unknowns(run)}); tip in mm, axis in degrees"]
    if run.ignored_faults:
        lines.append(f"not in the bound: the setup's faults {', '.join(run.ignored_faults)} (a world without them)")
    if len(run.poses) == 1:
        pose, bound = run.poses[0], run.bounds[0]
        lines.append(f"tip {' '.join(f'{v:g}' for v in pose.tip_in_eye)} mm, axis "
                     f"{' '.join(f'{v:.4f}' for v in pose.axis)}")  # fmt: skip
        if not bound.ok:
            return "\n".join([*lines, f"no bound: {bound.status} ({bound.detail})"])
        sd = " ".join(f"{v:.3g}" for v in bound.tip_sd_mm)
        return "\n".join([
            *lines,
            f"tip sd (x y z): {sd} mm; total {bound.tip_mm:.3g} mm",
            f"axis sd: {bound.axis_deg:.3g} deg (tilts {' '.join(f'{v:.3g}' for v in bound.axis_sd_deg)})",
            f"{bound.pixels} pixel values carry information; the clip took {100 * bound.clipped_share:.0f} % of the "
            "tip's",
        ])  # fmt: skip
    lines.append(f"{'step':>4} {'x':>7} {'y':>7} {'z':>7} {'sd x':>9} {'sd y':>9} {'sd z':>9} {'tip':>9} {'axis':>9}"
                 " status")  # fmt: skip
    for step, (pose, bound) in enumerate(zip(run.poses, run.bounds, strict=True)):
        x, y, z = pose.tip_in_eye
        sx, sy, sz = bound.tip_sd_mm
        lines.append(f"{step:>4} {x:>7.3f} {y:>7.3f} {z:>7.3f} {sx:>9.3g} {sy:>9.3g} {sz:>9.3g} {bound.tip_mm:>9.3g} "
                     f"{bound.axis_deg:>9.3g} {bound.status}")  # fmt: skip
    totals = run.totals_mm()
    found = totals[np.isfinite(totals)]
    if len(found) == 0:
        return "\n".join([*lines, "no pose has a bound"])
    lines.append(
        f"tip bound over {len(found)} of {len(totals)} poses: RMS {np.sqrt(np.mean(found**2)):.3g} mm, mean "
        f"{found.mean():.3g}, 95th percentile {np.percentile(found, 95):.3g}, max {found.max():.3g} mm"
    )
    return "\n".join(lines)


def write_bound(out: Path, run: BoundRun) -> list[Path]:
    """``bound.csv`` (a row per pose, :data:`BOUND_COLUMNS`) and, for a path, ``bound.png`` in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    table = out / "bound.csv"
    with table.open("w", newline="", encoding="utf-8") as stream:
        writer = csv.writer(stream)
        writer.writerow(BOUND_COLUMNS)
        for step, (pose, bound) in enumerate(zip(run.poses, run.bounds, strict=True)):
            tip = bound.tip_mm if bound.ok else np.nan
            axis = bound.axis_deg if bound.ok else np.nan
            values = [*pose.tip_in_eye, *bound.tip_sd_mm, tip, axis]
            writer.writerow([step, bound.status, *(f"{v:.6g}" for v in values), bound.pixels,
                             f"{bound.clipped_share:.4f}"])  # fmt: skip
    written = [table]
    if len(run.poses) > 1:
        sd = np.array([b.tip_sd_mm for b in run.bounds])
        curves = {"total": run.totals_mm(), "x": sd[:, 0], "y": sd[:, 1], "z": sd[:, 2]}
        axes = {"axis": np.array([b.axis_deg if b.ok else np.nan for b in run.bounds])}
        plot_per_step(out / "bound.png", {"tip [mm]": curves, "axis [deg]": axes}, "bound (1 sigma)",
                      "Cramer-Rao bound along the path", log=True)  # fmt: skip
        written.append(out / "bound.png")
    return written
