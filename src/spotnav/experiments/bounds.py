"""The Cramer-Rao bound beside a study's errors: the bound of each pose, and the RMS error against the bound's RMS.

:func:`path_bounds` computes :func:`spotnav.pose.bound.pose_bound` for every pose of a path in each world, in
the runner's workers (the axis through the insertion point, as the precise method constrains it).
:func:`rms_against_bound` takes the root mean square of the tip errors and of the bound over the same frames:
their ratio is 1 for an efficient, unbiased localizer. Chapter 6's error tables
(:mod:`spotnav.experiments.chapter6`) and the efficiency study (:mod:`spotnav.experiments.efficiency`) use both.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping, Sequence
from typing import TypeVar

import numpy as np

from spotnav.experiments.runner import FrameJob, FrameResult, FrameRunner
from spotnav.pose.bound import PoseBound, pose_bound
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose

__all__ = ["bound_of_job", "bound_rows", "path_bounds", "ratio_text", "rms_against_bound"]

_Key = TypeVar("_Key", bound=Hashable)


def bound_of_job(job: FrameJob) -> PoseBound:
    """The bound of the job's pose in the job's world, the axis through the insertion point."""
    return pose_bound(job.world, job.pose)


def path_bounds(
    runner: FrameRunner, worlds: Mapping[_Key, Setup], poses: Sequence[InstrumentPose], label: str
) -> dict[_Key, list[PoseBound]]:
    """The bound of every pose in each world, by the world's key, in the order of ``poses``."""
    keys = list(worlds)
    jobs = [FrameJob(worlds[key], pose, 0, ()) for key in keys for pose in poses]
    bounds = runner.map(bound_of_job, jobs, label)
    return {key: bounds[k * len(poses) : (k + 1) * len(poses)] for k, key in enumerate(keys)}


def rms_against_bound(errors_xyz_mm: np.ndarray, bounds: Sequence[PoseBound]) -> tuple[float, float, int]:
    """The RMS tip error and the bound's RMS over the frames with both, and their count.

    Parameters
    ----------
    errors_xyz_mm : ndarray, shape (n, 3)
        Estimate minus truth per frame, mm; NaN rows: no pose.
    bounds : sequence of PoseBound
        Each frame's pose's bound (``n`` of them).

    Returns
    -------
    rms_mm, bound_rms_mm : float
        Root mean square of the Euclidean error and of the bound's total tip SD (:attr:`PoseBound.tip_mm`),
        mm; NaN without such frames.
    frames : int
    """
    bound_mm = np.array([b.tip_mm if b.ok else np.nan for b in bounds])
    both = np.all(np.isfinite(errors_xyz_mm), axis=1) & np.isfinite(bound_mm)
    if not both.any():
        return float("nan"), float("nan"), 0
    rms = float(np.sqrt(np.mean(np.sum(errors_xyz_mm[both] ** 2, axis=1))))
    return rms, float(np.sqrt(np.mean(bound_mm[both] ** 2))), int(both.sum())


def bound_rows(
    results: Mapping[str, Mapping[str, Sequence[FrameResult]]],
    bounds: Mapping[str, Sequence[PoseBound]],
    labels: Sequence[str],
) -> list[list[str]]:
    """Three rows of a report's table: each method's RMS error, the bound's RMS over the same frames, and their ratio.

    Per key of ``results`` (a beam count): ``-`` under the thesis's printed numbers, then one cell per method of
    ``labels`` (``no calibration`` where ``results`` lacks it); ``bounds`` holds each pose's bound by that key.
    """
    names = ("RMS error [mm]", "bound's RMS, same poses [mm]", "RMS error / bound's RMS")
    rows: list[list[str]] = [[name] for name in names]
    for key, by_label in results.items():
        for row in rows:
            row.append("-")
        for label in labels:
            cells = ("no calibration",) * 3
            if label in by_label:
                errors = np.array([r.error_xyz_mm for r in by_label[label]]).reshape(-1, 3)
                rms, bound, count = rms_against_bound(errors, bounds[key])
                cells = ("no pose",) * 3 if not count else (f"{rms:.5f}", f"{bound:.6f}", ratio_text(rms / bound))
            for row, cell in zip(rows, cells, strict=True):
                row.append(cell)
    return rows


def ratio_text(ratio: float) -> str:
    """A ratio to the bound for a report: three significant digits, whole numbers from 1000 up."""
    return f"{ratio:.0f}" if ratio >= 1000 else f"{ratio:.3g}"
