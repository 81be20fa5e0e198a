"""Evaluate a ``poses.csv`` against the truth: what ``spotnav evaluate`` prints and writes.

The two files are joined on ``image``, by file name (the folders may differ);
rows without one (a video's frames, from ``spotnav track`` and ``spotnav
render --out FILE.mkv``) join on ``frame``.
The tip error is the distance between the estimated and the true tip over the
``ok`` rows; the bias is the mean of the error's components; the axis error is
the angle between the estimated and the true axis.
"""

from __future__ import annotations

import csv
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spotnav.app.figures import plot_errors_by_status, plot_track_by_status
from spotnav.errors import InputError
from spotnav.files.poses import KnownPose, PoseRow
from spotnav.pose.estimate import within_sigmas

__all__ = ["Evaluation", "FrameEvaluation", "evaluate_poses", "evaluation_text", "write_evaluation"]


@dataclass(frozen=True)
class FrameEvaluation:
    """One frame's estimate against its truth.

    Attributes
    ----------
    image : str
        The file name both files share (``frame N`` for a video's frame).
    status : str
    error_xyz_mm : ndarray, shape (3,)
        Estimate minus truth, mm (NaN without a pose).
    axis_error_deg : float
        Angle between the axes, degrees (NaN without a pose or a true axis).
    sigma_mm : float
        The estimate's own 1-sigma tip uncertainty (NaN without one).
    true_tip_mm : ndarray, shape (3,)
        The true tip, eye frame, mm.
    """

    image: str
    status: str
    error_xyz_mm: np.ndarray
    axis_error_deg: float
    sigma_mm: float = float("nan")
    true_tip_mm: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))

    @property
    def error_mm(self) -> float:
        """Distance from the true tip, mm (NaN without a pose)."""
        return float(np.linalg.norm(self.error_xyz_mm))


@dataclass(frozen=True)
class Evaluation:
    """All frames' errors and their summary over the ``ok`` frames (NaN when there is none).

    Attributes
    ----------
    frames : tuple of FrameEvaluation
        In the order of the poses file.
    counts : dict of str to int
        Frames per status.
    mean_mm, median_mm, p95_mm, max_mm : float
        Tip error statistics, mm.
    bias_mm : ndarray, shape (3,)
        Mean error per axis (x, y, z), mm.
    axis_mean_deg, axis_max_deg : float
        Axis angle error, degrees.
    within_3_sigma : float
        Fraction of the ``ok`` frames with a ``sigma_mm`` whose 3-D error is within 3 of its 3-D standard error
        (:func:`spotnav.pose.estimate.within_sigmas`; NaN without any).
    unposed : int
        Truth rows without a pose row (a run stopped early), left out.
    """

    frames: tuple[FrameEvaluation, ...]
    counts: dict[str, int]
    mean_mm: float
    median_mm: float
    p95_mm: float
    max_mm: float
    bias_mm: np.ndarray
    axis_mean_deg: float
    axis_max_deg: float
    within_3_sigma: float = float("nan")
    unposed: int = 0


def _frame_key(image: str, frame: int | None) -> str:
    """The join key of a row: its image's file name, or ``frame N`` for a row without an image."""
    name = Path(image).name
    return name if name or frame is None else f"frame {frame}"


def _by_name(keys: Sequence[str], what: str) -> dict[str, int]:
    index: dict[str, int] = {}
    for position, key in enumerate(keys):
        if key in index:
            raise InputError(f"{what}: the image {key} appears twice")
        index[key] = position
    return index


def _listed(names: Sequence[str]) -> str:
    return ", ".join(sorted(names)[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")


def evaluate_poses(poses: Sequence[PoseRow], truth: Sequence[KnownPose]) -> Evaluation:
    """Join estimates and truth on the image's file name (or frame, without one) and measure the errors.

    Truth rows without a pose row (a run that stopped early) are counted and left out.

    Raises
    ------
    InputError
        Naming the pose rows without truth, or an image listed twice.
    """
    estimated = _by_name([_frame_key(p.image, p.frame) for p in poses], "poses")
    known = _by_name([_frame_key(t.image.name, t.frame) for t in truth], "truth")
    missing_truth = sorted(set(estimated) - set(known))
    missing_pose = sorted(set(known) - set(estimated))
    if missing_truth:
        raise InputError(f"no truth for {len(missing_truth)} image(s): {_listed(missing_truth)}")
    frames = []
    for name, position in estimated.items():
        row, true = poses[position], truth[known[name]]
        error = np.full(3, np.nan)
        angle = float("nan")
        if row.status == "ok" and row.tip_in_eye is not None and row.axis is not None:
            error = row.tip_in_eye - true.tip_in_eye
            if true.axis is not None:
                cosine = row.axis @ true.axis / (np.linalg.norm(row.axis) * np.linalg.norm(true.axis))
                angle = float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))
        frames.append(FrameEvaluation(name, row.status, error, angle, row.sigma_mm, true.tip_in_eye))
    ok = [f for f in frames if f.status == "ok"]
    errors = np.array([f.error_mm for f in ok])
    angles = np.array([f.axis_error_deg for f in ok if np.isfinite(f.axis_error_deg)])

    def stat(values: np.ndarray, pick: str) -> float:
        if len(values) == 0:
            return float("nan")
        return float(np.percentile(values, 95)) if pick == "p95" else float(getattr(np, pick)(values))

    sigmaed = [f for f in ok if np.isfinite(f.sigma_mm)]
    return Evaluation(
        frames=tuple(frames),
        counts=dict(Counter(f.status for f in frames).most_common()),
        mean_mm=stat(errors, "mean"),
        median_mm=stat(errors, "median"),
        p95_mm=stat(errors, "p95"),
        max_mm=stat(errors, "max"),
        bias_mm=np.mean([f.error_xyz_mm for f in ok], axis=0) if ok else np.full(3, np.nan),
        axis_mean_deg=stat(angles, "mean"),
        axis_max_deg=stat(angles, "max"),
        within_3_sigma=stat(within_sigmas([f.error_mm for f in sigmaed], [f.sigma_mm for f in sigmaed]), "mean"),
        unposed=len(missing_pose),
    )


def evaluation_text(evaluation: Evaluation) -> str:
    """The summary as ``spotnav evaluate`` prints it."""
    counts = ", ".join(f"{n} {status}" for status, n in evaluation.counts.items())
    ok = evaluation.counts.get("ok", 0)
    bias = " / ".join(f"{v:+.4f}" for v in evaluation.bias_mm)
    lines = [f"frames: {len(evaluation.frames)} ({counts})"]
    if evaluation.unposed:
        lines.append(f"{evaluation.unposed} truth rows have no pose row (a run stopped early?): left out")
    if ok:
        lines += [
            f"tip error over the {ok} ok frames [mm]: mean {evaluation.mean_mm:.4f}, "
            f"median {evaluation.median_mm:.4f}, 95th percentile {evaluation.p95_mm:.4f}, max {evaluation.max_mm:.4f}",
            f"bias (mean error x / y / z) [mm]: {bias}",
            f"axis error [deg]: mean {evaluation.axis_mean_deg:.3f}, max {evaluation.axis_max_deg:.3f}",
        ]
    if np.isfinite(evaluation.within_3_sigma):
        lines.append(
            f"within 3 sigma: {100 * evaluation.within_3_sigma:.0f} % of the ok frames "
            "(the 3-D error against 3 sqrt(3) sigma_mm, its 3-D standard error: sigma_mm is per axis)"
        )
    return "\n".join(lines)


def _errors_title(evaluation: Evaluation) -> str:
    """``errors.png``'s title: the mean and max over the ok frames, or that there is none (never ``nan``)."""
    if not evaluation.counts.get("ok", 0):
        return f"tip error per frame: no ok frame among {len(evaluation.frames)}"
    return f"tip error per frame: mean {evaluation.mean_mm:.4f} mm, max {evaluation.max_mm:.4f} mm over ok frames"


def write_evaluation(out: Path, evaluation: Evaluation) -> list[Path]:
    """Write ``errors.csv``, ``errors.png`` and ``track.png`` into ``out``; return their paths.

    ``errors.csv`` has one row per frame, ``errors.png`` the error per frame by
    status, ``track.png`` the estimated tips against the true path, in 3D, and
    the frames without a pose at their true tips; both figures colour each status
    as :mod:`spotnav.app.status_style` does.
    """
    out.mkdir(parents=True, exist_ok=True)
    table = out / "errors.csv"
    with table.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(["image", "status", "error_mm", "error_x_mm", "error_y_mm", "error_z_mm", "axis_error_deg"])
        for f in evaluation.frames:
            values = [f.error_mm, *f.error_xyz_mm, f.axis_error_deg]
            writer.writerow([f.image, f.status, *("" if not np.isfinite(v) else f"{v:.6f}" for v in values)])
    figure = out / "errors.png"
    plot_errors_by_status(
        figure,
        [f.image for f in evaluation.frames],
        np.array([f.error_mm for f in evaluation.frames]),
        [f.status for f in evaluation.frames],
        _errors_title(evaluation),
    )
    truth = np.array([f.true_tip_mm for f in evaluation.frames])
    estimated = truth + np.array([f.error_xyz_mm for f in evaluation.frames])
    track = out / "track.png"
    title = f"estimated tips ({evaluation.counts.get('ok', 0)} ok frames) against the true path"
    plot_track_by_status(track, truth, estimated, [f.status for f in evaluation.frames], title)
    return [table, figure, track]
