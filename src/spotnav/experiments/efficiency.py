"""Efficiency: the precise method's error on the helix against the Cramer-Rao bound, split into bias and spread.

Every helix pose (1 W, one and three beams, the default and the thesis's exposure) gets its bound
(:func:`spotnav.pose.bound.pose_bound`, the axis through the insertion point as the precise method constrains it)
and two frames with independent noise. Each frame is localized by the precise method, then refined from that pose
by the photometric model fit (:func:`spotnav.pose.model_fit.fit_model_to_frame`), the maximum-likelihood estimate
that knows the world as the bound does. Two draws per pose split an estimator's mean square error into its spread
(the noise's share, which the bound limits) and its bias (which the bound does not include):

    spread^2 = mean_poses |e1 - e2|^2 / 2,      bias^2 = mean_poses |(e1 + e2) / 2|^2 - spread^2 / 2,

so that ``RMS^2 = bias^2 + spread^2`` over the same frames (docs/methods.md, "Efficiency").
"""

from __future__ import annotations

import csv
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spotnav.app.figures import plot_per_step
from spotnav.app.paths import path_poses
from spotnav.app.status_style import status_counts
from spotnav.experiments.bounds import ratio_text
from spotnav.experiments.chapter6 import EXPOSURES, PRECISE
from spotnav.experiments.frame import render_timed
from spotnav.experiments.report import Experiment, Options, markdown_table
from spotnav.experiments.runner import FrameJob, FrameResult, Variant, localize_variants
from spotnav.experiments.scenes import BEAMS, PATH_SEEDS, thesis_world, with_true_edge
from spotnav.optics.render import Renderer
from spotnav.pose.bound import PoseBound, pose_bound
from spotnav.pose.model_fit import ModelFit, fit_model_to_frame
from spotnav.setup.geometry import InstrumentPose, angles_between
from spotnav.setup.sections import Instrument

__all__ = [
    "TARGET_RATIO",
    "Draw",
    "ErrorSplit",
    "PoseEfficiency",
    "efficiency_of_job",
    "run_efficiency",
    "split_error",
]

SECOND_DRAW = 500_000  # the second frame of a pose: its first's noise seed plus this
MAX_POSES = 25  # a full reproduction's 100 poses at 5000 px would fit the model some 800 times: hours, for no more
TARGET_RATIO = 1.5  # issue 45: the measured RMS error within this factor of the bound's RMS
FIT = "model fit"
FIT_BIAS = (
    "The model fit knows what the bound assumes (the world's albedo, light and camera): its spread should be the "
    "bound's and its bias a small share of it. A bias of its own, well over its spread, would say that the "
    'renderer and the photometric model that the bound and the fit share differ (docs/methods.md, "The bound").'
)


@dataclass(frozen=True)
class Draw:
    """One noisy frame of a pose: the precise method's estimate and the model fit started from it.

    Attributes
    ----------
    seed : int
        The frame's noise seed.
    precise : FrameResult
    fit : ModelFit or None
        ``None`` where the precise method gave no pose to start from.
    fit_ms : float
        The fit's wall time.
    """

    seed: int
    precise: FrameResult
    fit: ModelFit | None
    fit_ms: float

    @property
    def fit_status(self) -> str:
        """The fit's status, or ``no start`` without a precise pose."""
        return "no start" if self.fit is None else self.fit.status

    @property
    def fit_error_xyz_mm(self) -> np.ndarray:
        """The fitted tip minus the true one, shape (3,), mm; NaN without a fit."""
        if self.fit is None or self.fit.pose is None:
            return np.full(3, np.nan)
        error: np.ndarray = self.fit.pose.tip_in_eye - self.precise.truth.tip_in_eye
        return error

    @property
    def fit_axis_error_deg(self) -> float:
        """The angle between the fitted and the true axis, degrees; NaN without a fit."""
        if self.fit is None or self.fit.pose is None:
            return float("nan")
        return float(np.degrees(angles_between(self.fit.pose.axis, self.precise.truth.axis)))


@dataclass(frozen=True)
class PoseEfficiency:
    """One pose's bound and its two draws."""

    bound: PoseBound
    draws: tuple[Draw, Draw]


def efficiency_of_job(job: FrameJob) -> PoseEfficiency:
    """The job's pose: its bound, and two frames (seeds ``job.seed`` and ``job.seed + SECOND_DRAW``) each localized
    by the job's one variant (the precise method) and refined by the model fit in the job's world."""
    bound = pose_bound(job.world, job.pose)
    renderer = Renderer(job.world)
    draws = []
    for seed in (job.seed, job.seed + SECOND_DRAW):
        image, render_ms = render_timed(renderer, job.pose, seed)
        (precise,) = localize_variants(image, job, render_ms, job.variants)
        start = time.perf_counter()
        fit = None
        if precise.estimate.ok:
            fit = fit_model_to_frame(image, job.world, InstrumentPose(*precise.estimate.pose()))
        draws.append(Draw(seed, precise, fit, 1000 * (time.perf_counter() - start)))
    return PoseEfficiency(bound, (draws[0], draws[1]))


@dataclass(frozen=True)
class ErrorSplit:
    """An estimator's tip error over a path's poses against the bound, and its split into bias and spread.

    Attributes
    ----------
    frames : int
        Frames with a pose and a bound.
    rms_mm, bound_rms_mm : float
        RMS Euclidean error, and the bound's RMS (:attr:`PoseBound.tip_mm`) over the same frames, mm.
    bias_mm, spread_mm : float
        The RMS over poses of the error's mean (the bias) and the RMS of its scatter about that mean (the spread),
        from the poses with both draws, mm. NaN without such poses.
    mean_xyz_mm : ndarray, shape (3,)
        The mean signed error along eye x, y and z over the frames, mm.
    axis_rms_deg, bound_axis_rms_deg : float
        RMS angle between the estimated and the true axis, and the bound's (:attr:`PoseBound.axis_deg`), degrees.
    """

    frames: int
    rms_mm: float
    bound_rms_mm: float
    bias_mm: float
    spread_mm: float
    mean_xyz_mm: np.ndarray
    axis_rms_deg: float
    bound_axis_rms_deg: float

    @property
    def ratio(self) -> float:
        """The RMS error over the bound's RMS."""
        return self.rms_mm / self.bound_rms_mm if self.frames else float("nan")

    def text(self, value: float, ratio: bool = False) -> str:
        """A figure of the split for a report (``.2e``, or :func:`ratio_text` for a ratio), or ``-`` and why it is
        missing: no frame with a pose and a bound, or (bias and spread) no pose with both draws."""
        if np.isfinite(value):
            return ratio_text(value) if ratio else f"{value:.2e}"
        return "- (no frame with a pose and a bound)" if not self.frames else "- (no pose with both draws)"


def split_error(errors_xyz_mm: np.ndarray, axis_errors_deg: np.ndarray, bounds: Sequence[PoseBound]) -> ErrorSplit:
    """Measure an estimator on two draws per pose against the poses' bounds.

    Parameters
    ----------
    errors_xyz_mm : ndarray, shape (n, 2, 3)
        Estimate minus truth per pose and draw, mm; NaN: no pose.
    axis_errors_deg : ndarray, shape (n, 2)
        The angle between the estimated and the true axis, degrees.
    bounds : sequence of PoseBound
        Each pose's bound.

    Returns
    -------
    ErrorSplit
    """
    tip = np.array([b.tip_mm if b.ok else np.nan for b in bounds])
    axis = np.array([b.axis_deg if b.ok else np.nan for b in bounds])
    valid = np.all(np.isfinite(errors_xyz_mm), axis=2) & np.isfinite(tip)[:, None]  # (n, 2)
    nan = float("nan")
    if not valid.any():
        return ErrorSplit(0, nan, nan, nan, nan, np.full(3, nan), nan, nan)
    pairs = valid.all(axis=1)
    bias, spread = nan, nan
    if pairs.any():
        e1, e2 = errors_xyz_mm[pairs, 0], errors_xyz_mm[pairs, 1]
        spread_sq = float(np.mean(np.sum((e1 - e2) ** 2, axis=1)) / 2.0)
        bias_sq = float(np.mean(np.sum(((e1 + e2) / 2.0) ** 2, axis=1))) - spread_sq / 2.0
        bias, spread = float(np.sqrt(max(bias_sq, 0.0))), float(np.sqrt(spread_sq))
    used = valid & pairs[:, None] if pairs.any() else valid  # the split's frames: RMS^2 = bias^2 + spread^2 on them
    per_frame_tip = np.broadcast_to(tip[:, None], valid.shape)[used]
    per_frame_axis = np.broadcast_to(axis[:, None], valid.shape)[used]
    return ErrorSplit(
        frames=int(used.sum()),
        rms_mm=float(np.sqrt(np.mean(np.sum(errors_xyz_mm[used] ** 2, axis=1)))),
        bound_rms_mm=float(np.sqrt(np.mean(per_frame_tip**2))),
        bias_mm=bias,
        spread_mm=spread,
        mean_xyz_mm=errors_xyz_mm[used].mean(axis=0),
        axis_rms_deg=float(np.sqrt(np.mean(axis_errors_deg[used] ** 2))),
        bound_axis_rms_deg=float(np.sqrt(np.mean(per_frame_axis**2))),
    )


def _errors(poses: Sequence[PoseEfficiency]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per estimator: its tip errors, shape (n, 2, 3), mm, and axis errors, shape (n, 2), degrees, by pose and draw."""
    precise = np.array([[d.precise.error_xyz_mm for d in p.draws] for p in poses]).reshape(-1, 2, 3)
    precise_axis = np.array([[d.precise.rotation_error_deg[2] for d in p.draws] for p in poses]).reshape(-1, 2)
    fit = np.array([[d.fit_error_xyz_mm for d in p.draws] for p in poses]).reshape(-1, 2, 3)
    fit_axis = np.array([[d.fit_axis_error_deg for d in p.draws] for p in poses]).reshape(-1, 2)
    return {PRECISE: (precise, precise_axis), FIT: (fit, fit_axis)}


def _splits(poses: Sequence[PoseEfficiency]) -> dict[str, ErrorSplit]:
    """The precise method's and the model fit's splits over the poses."""
    bounds = [p.bound for p in poses]
    return {name: split_error(tip, axis, bounds) for name, (tip, axis) in _errors(poses).items()}


def _counts(statuses: Sequence[str]) -> str:
    return status_counts(Counter(statuses), "none")


# --- the study --------------------------------------------------------------------------------------------------


def run_efficiency(options: Options) -> Experiment:
    """The helix at 1 W, one and three beams, both exposures: the bound, the precise method and the model fit."""
    size, count = options.size_px, min(options.count, MAX_POSES)
    insertion = Instrument().insertion_in_eye
    poses = path_poses("helix", count, insertion)
    cases = {(b, regime): thesis_world(size, beams, 1.0, exposure_stops=stops) for b, beams in BEAMS.items()
             for regime, stops in EXPOSURES.items()}  # fmt: skip
    jobs = []
    for world in cases.values():
        variants = (Variant(PRECISE, with_true_edge(world), "precise"),)
        jobs += [FrameJob(world, pose, PATH_SEEDS["helix"] + i, variants) for i, pose in enumerate(poses)]
    outputs: list[PoseEfficiency] = options.runner.map(efficiency_of_job, jobs, "efficiency")
    results = {key: outputs[k * count : (k + 1) * count] for k, key in enumerate(cases)}
    splits = {key: _splits(by_pose) for key, by_pose in results.items()}
    _write_csv(options.out / "efficiency.csv", size, results)
    _plot(options.out / "efficiency.png", size, results)
    lines = [
        "## Efficiency: the precise method against the Cramer-Rao bound",
        "",
        f"The helix ({count} poses, at most {MAX_POSES}; {size} px, 1 W), one and three beams, in both exposures "
        "of chapter 6. Per pose: "
        "the Cramer-Rao bound of the tip from one frame (`spotnav.pose.bound`: the photometric model of the light, "
        "its soft edge, defocus, clip, response and noise; the power and the roll of several beams unknown; the axis "
        "through the insertion point, as the precise method constrains it), and two frames with independent noise. "
        "Each frame is localized by the precise method (the exact setup), then refined from that pose by the model "
        "fit (`spotnav.pose.model_fit`): the maximum-likelihood estimate that knows the world as the bound does, the "
        "retina's albedo among it. The two draws split the mean square error over the poses into bias^2 (the "
        "error's mean per pose, which the bound does not include) and spread^2 (its scatter, which the bound "
        f"limits): RMS^2 = bias^2 + spread^2. Target (issue 45): the RMS error within {TARGET_RATIO:g} x the "
        "bound's RMS.",
        "",
    ]
    for b in BEAMS:
        lines += [f"### {b}", "", *_table(size, {r: splits[(b, r)] for r in EXPOSURES}), ""]
        lines += [*_statuses_lines({r: results[(b, r)] for r in EXPOSURES}), ""]
    lines += [*_verdict_lines(splits), "", FIT_BIAS, "", "![error and bound along the helix](efficiency.png)"]
    summary = "RMS tip error over the Cramer-Rao bound's RMS on the same frames: " + "; ".join(
        f"{b}, {r}: precise {_times(s[PRECISE])}, model fit {_times(s[FIT])}" for (b, r), s in splits.items()
    )
    return Experiment("efficiency", "\n".join(lines), summary)


def _times(split: ErrorSplit) -> str:
    """``296 x (bound 2.40e-04 mm, 50 frames)``, or why there is no ratio."""
    if not split.frames:
        return "no frame with a pose and a bound"
    return f"{ratio_text(split.ratio)} x (bound {split.bound_rms_mm:.2e} mm, {split.frames} frames)"


def _table(size: int, splits: Mapping[str, Mapping[str, ErrorSplit]]) -> list[str]:
    header = ["size [px]", "exposure", "bound RMS [mm]", "precise RMS [mm]", "ratio", "precise bias [mm]"]
    header += ["precise spread [mm]", "spread / bound", "fit RMS [mm]", "ratio", "fit bias [mm]", "fit spread / bound"]
    header += ["axis bound RMS [deg]", "precise axis RMS [deg]", "fit axis RMS [deg]"]
    rows = []
    for regime, by_method in splits.items():
        p, f = by_method[PRECISE], by_method[FIT]
        rows.append([
            str(size), regime, p.text(p.bound_rms_mm), p.text(p.rms_mm), p.text(p.ratio, True), p.text(p.bias_mm),
            p.text(p.spread_mm), p.text(p.spread_mm / p.bound_rms_mm, True), f.text(f.rms_mm), f.text(f.ratio, True),
            f.text(f.bias_mm), f.text(f.spread_mm / f.bound_rms_mm, True), p.text(p.bound_axis_rms_deg),
            p.text(p.axis_rms_deg), f.text(f.axis_rms_deg),
        ])  # fmt: skip
    return markdown_table(header, rows)


def _statuses_lines(results: Mapping[str, Sequence[PoseEfficiency]]) -> list[str]:
    """Per exposure: the bounds', the precise method's and the fit's statuses, and the share the clip took."""
    lines = []
    for regime, poses in results.items():
        draws = [d for p in poses for d in p.draws]
        shares = np.array([p.bound.clipped_share for p in poses])
        shares = shares[np.isfinite(shares)]
        clipped = f"the clip took {100 * shares.mean():.0f} %" if len(shares) else "no bound to tell what the clip took"
        lines.append(
            f"- {regime}: bounds {_counts([p.bound.status for p in poses])} ({clipped} "
            f"of the tip's information on average); precise {_counts([d.precise.estimate.status for d in draws])}; "
            f"model fit {_counts([d.fit_status for d in draws])}."
        )
    return lines


def _verdict_lines(splits: Mapping[tuple[str, str], Mapping[str, ErrorSplit]]) -> list[str]:
    """Which cases meet the target, and for those that do not, how much of the mean square error is bias."""
    lines = ["Against the target:", ""]
    for (b, regime), by_method in splits.items():
        p, f = by_method[PRECISE], by_method[FIT]
        mean = ", ".join(f"{v:+.1e}" for v in p.mean_xyz_mm)
        if not p.frames:
            text = "not measured: no frame with a pose and a bound"
        elif p.ratio <= TARGET_RATIO:
            text = f"within {TARGET_RATIO:g} x the bound ({ratio_text(p.ratio)} x)"
        elif not np.isfinite(p.bias_mm):
            text = f"{ratio_text(p.ratio)} x the bound (no bias and spread: no pose with both draws)"
        else:
            share = (p.bias_mm / p.rms_mm) ** 2
            spread = ratio_text(p.spread_mm / p.bound_rms_mm)
            text = (
                f"{ratio_text(p.ratio)} x the bound: bias {p.bias_mm:.2e} mm is {100 * share:.0f} % of its mean square "
                f"error (mean error along x, y, z: {mean} mm), and its spread alone is {spread} x the bound"
            )
        fit = "no frame with a pose and a bound"
        if f.frames:
            fit = f"{ratio_text(f.ratio)} x (its spread {f.text(f.spread_mm / f.bound_rms_mm, True)} x)"
        lines.append(f"- {b}, {regime}: the precise method is {text}; the model fit from it reaches {fit}.")
    return lines


def _write_csv(path: Path, size: int, results: Mapping[tuple[str, str], Sequence[PoseEfficiency]]) -> None:
    """Every frame: its case, the pose's bound, and the precise method's and the model fit's errors."""
    columns = ["size_px", "beams", "exposure", "step", "seed", "true_x", "true_y", "true_z", "bound_status"]
    columns += ["bound_x_mm", "bound_y_mm", "bound_z_mm", "bound_mm", "bound_axis_deg", "clipped_share"]
    columns += ["precise_status", "precise_error_x", "precise_error_y", "precise_error_z", "precise_error_mm"]
    columns += ["precise_axis_error_deg", "fit_status", "fit_error_x", "fit_error_y", "fit_error_z", "fit_error_mm"]
    columns += ["fit_axis_error_deg", "fit_chi2_per_pixel", "fit_steps", "render_ms", "precise_ms", "fit_ms"]
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(columns)
        for (b, regime), poses in results.items():
            for step, pose in enumerate(poses):
                bound = pose.bound
                for draw in pose.draws:
                    r = draw.precise
                    fit_error = draw.fit_error_xyz_mm
                    numbers = [*bound.tip_sd_mm, bound.tip_mm, bound.axis_deg, bound.clipped_share]
                    numbers += [*r.error_xyz_mm, r.error_mm, r.rotation_error_deg[2]]
                    fit_numbers = [*fit_error, float(np.linalg.norm(fit_error)), draw.fit_axis_error_deg]
                    fit_numbers.append(draw.fit.chi2_per_pixel if draw.fit is not None else np.nan)
                    writer.writerow(
                        [size, BEAMS[b], regime, step, draw.seed, *(f"{v:.6f}" for v in r.truth.tip_in_eye)]
                        + [bound.status, *(_number(v) for v in numbers[:6]), r.estimate.status]
                        + [_number(v) for v in numbers[6:]]
                        + [draw.fit_status, *(_number(v) for v in fit_numbers)]
                        + [draw.fit.steps if draw.fit is not None else ""]
                        + [f"{r.render_ms:.1f}", f"{r.localize_ms:.1f}", f"{draw.fit_ms:.1f}"]
                    )


def _number(value: float) -> str:
    return "" if not np.isfinite(value) else f"{value:.4e}"


def _plot(path: Path, size: int, results: Mapping[tuple[str, str], Sequence[PoseEfficiency]]) -> None:
    """Per case, along the helix: the RMS of the two draws' errors of each estimator (of the one draw with a pose
    where only one has), and the bound."""
    panels = {}
    for (b, regime), poses in results.items():
        curves = {}
        for name, (tip, _) in _errors(poses).items():
            squares = np.sum(tip**2, axis=2)
            found = np.isfinite(squares)
            curves[name] = np.sqrt(
                np.where(found, squares, 0.0).sum(axis=1) / np.where(found.any(axis=1), found.sum(axis=1), np.nan)
            )
        curves["bound"] = np.array([p.bound.tip_mm if p.bound.ok else np.nan for p in poses])
        panels[f"{b}, {regime}"] = curves
    title = f"Tip error (RMS of two draws) and the Cramer-Rao bound along the helix, 1 W, {size} px"
    plot_per_step(path, panels, "tip error [mm]", title, log=True)
