"""Experiments: render known poses, localize them and measure the error.

This layer may do I/O (CSV, Markdown, progress bars); the algorithm modules
below it do none. Frames are seeded per pose, so results do not depend on the
number of worker processes.
"""

from __future__ import annotations

import csv
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from spotnav.config import Camera, Light, Setup
from spotnav.geometry import InstrumentPose, approximation_deviation
from spotnav.localize import PoseEstimate, localize
from spotnav.render import Renderer

__all__ = [
    "THESIS_TABLE_4_1_UM",
    "ErrorSummary",
    "Experiment",
    "FrameResult",
    "approximation_rows",
    "reproduce",
    "run_frames",
    "summarize",
    "working_volume_tips",
]

THESIS_TABLE_4_1_UM = {5: 0.08, 7: 0.23, 9: 0.49, 11: 0.91, 13: 1.51, 15: 2.34}


@dataclass(frozen=True)
class FrameResult:
    """One rendered and localized frame.

    Attributes
    ----------
    truth : InstrumentPose
    estimate : PoseEstimate
    render_ms, localize_ms : float
        Wall time of each stage.
    """

    truth: InstrumentPose
    estimate: PoseEstimate
    render_ms: float
    localize_ms: float

    @property
    def error_xyz_mm(self) -> np.ndarray:
        """Estimate minus truth, shape (3,), mm; NaN unless ``ok``."""
        if self.estimate.tip_in_eye is None:
            return np.full(3, np.nan)
        return self.estimate.tip_in_eye - self.truth.tip_in_eye

    @property
    def error_mm(self) -> float:
        """Euclidean tip error, mm; NaN unless ``ok``."""
        return float(np.linalg.norm(self.error_xyz_mm))


@dataclass(frozen=True)
class ErrorSummary:
    """Accuracy over a set of frames (``ok`` frames only)."""

    frames: int
    ok: int
    mean_mm: float
    max_mm: float
    bias_xyz_mm: np.ndarray
    render_ms: float
    localize_ms: float


def summarize(results: Sequence[FrameResult]) -> ErrorSummary:
    """Mean and max tip error, bias and median timings."""
    errors = np.array([r.error_mm for r in results])
    ok = np.isfinite(errors)
    xyz = np.array([r.error_xyz_mm for r in results]).reshape(-1, 3)
    return ErrorSummary(
        frames=len(results),
        ok=int(ok.sum()),
        mean_mm=float(errors[ok].mean()) if ok.any() else float("nan"),
        max_mm=float(errors[ok].max()) if ok.any() else float("nan"),
        bias_xyz_mm=xyz[ok].mean(axis=0) if ok.any() else np.full(3, np.nan),
        render_ms=float(np.median([r.render_ms for r in results])),
        localize_ms=float(np.median([r.localize_ms for r in results])),
    )


def working_volume_tips(count: int, seed: int = 0) -> np.ndarray:
    """Tips drawn uniformly in x, y in [-2.5, 2.5] mm and z in [3, 6] mm, shape (count, 3)."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-2.5, 2.5, count), rng.uniform(-2.5, 2.5, count), rng.uniform(3.0, 6.0, count)])


_WORKER: dict[str, object] = {}


def _init_worker(setup: Setup, method: str) -> None:
    _WORKER["renderer"] = Renderer(setup)
    _WORKER["setup"] = setup
    _WORKER["method"] = method


def _run_one(job: tuple[InstrumentPose, int]) -> FrameResult:
    pose, seed = job
    renderer = _WORKER["renderer"]
    assert isinstance(renderer, Renderer)
    start = time.perf_counter()
    image = renderer.render(pose, seed=seed)
    rendered = time.perf_counter()
    estimate = localize(image, renderer.setup, str(_WORKER["method"]))
    done = time.perf_counter()
    return FrameResult(pose, estimate, 1000 * (rendered - start), 1000 * (done - rendered))


def run_frames(
    setup: Setup,
    poses: Sequence[InstrumentPose],
    method: str = "thesis",
    *,
    seed: int = 0,
    workers: int = 1,
    label: str = "frames",
) -> list[FrameResult]:
    """Render and localize every pose; frame ``i`` uses noise seed ``seed + i``.

    Parameters
    ----------
    setup : Setup
    poses : sequence of InstrumentPose
    method : str
        A :data:`spotnav.localize.METHODS` name.
    seed : int
    workers : int
        Processes; 1 runs in this process. Results do not depend on it.
    label : str
        Progress bar text.
    """
    jobs = [(pose, seed + i) for i, pose in enumerate(poses)]
    bar = tqdm(total=len(jobs), desc=label, unit="frame", leave=False, disable=None)
    try:
        if workers <= 1:
            _init_worker(setup, method)
            results = []
            for job in jobs:
                results.append(_run_one(job))
                bar.update()
            return results
        with ProcessPoolExecutor(workers, initializer=_init_worker, initargs=(setup, method)) as pool:
            results = []
            for result in pool.map(_run_one, jobs, chunksize=max(1, len(jobs) // (4 * workers))):
                results.append(result)
                bar.update()
            return results
    finally:
        bar.close()


def approximation_rows() -> list[tuple[int, float, float, float, float]]:
    """Table 4.1: ``(beta_deg, thesis_um, gap_y_um, to_plane_um, along_ray_um)`` for 5..15 deg."""
    rows = []
    for beta, thesis in THESIS_TABLE_4_1_UM.items():
        deviation = approximation_deviation(np.radians(beta))
        rows.append((beta, thesis, deviation.gap_y_um, deviation.to_plane_um, deviation.along_ray_um))
    return rows


@dataclass(frozen=True)
class Experiment:
    """A finished experiment: a Markdown section and one line for the console."""

    name: str
    markdown: str
    summary: str


def _approximation_experiment(out: Path, **_: object) -> Experiment:
    rows = approximation_rows()
    with (out / "approximation.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["beta_deg", "thesis_um", "gap_y_um", "to_plane_um", "along_ray_um"])
        writer.writerows([[b, t, f"{g:.4f}", f"{p:.4f}", f"{a:.4f}"] for b, t, g, p, a in rows])
    lines = [
        "## Table 4.1: cone-sphere curve vs the cone-plane ellipse",
        "",
        "Sphere centre (3.7, 0, -6.35) mm in the cone frame, r = 12.5 mm (Table 4.2).",
        "",
        "| opening angle [deg] | thesis [um] | spotnav, y gap [um] | distance to plane [um] | along cone line [um] |",
        "| --- | --- | --- | --- | --- |",
    ]
    lines += [f"| {b} | {t:.2f} | {g:.3f} | {p:.3f} | {a:.3f} |" for b, t, g, p, a in rows]
    worst = max(abs(round(g, 2) - t) for _, t, g, _, _ in rows)
    return Experiment("approximation", "\n".join(lines), f"Table 4.1: largest difference to the thesis {worst:.3f} um")


def _write_frames_csv(path: Path, results: Sequence[FrameResult]) -> None:
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(
            [
                "frame",
                "true_x",
                "true_y",
                "true_z",
                "status",
                "x_mm",
                "y_mm",
                "z_mm",
                "error_mm",
                "error_x",
                "error_y",
                "error_z",
                "render_ms",
                "localize_ms",
            ]
        )
        for i, r in enumerate(results):
            estimate = r.estimate.tip_in_eye if r.estimate.tip_in_eye is not None else np.full(3, np.nan)
            numbers = [*r.truth.tip_in_eye, r.estimate.status, *estimate, r.error_mm, *r.error_xyz_mm]
            writer.writerow(
                [
                    i,
                    *(f"{v:.6f}" if isinstance(v, float) else v for v in numbers),
                    f"{r.render_ms:.1f}",
                    f"{r.localize_ms:.1f}",
                ]
            )


def _summary_row(label: str, s: ErrorSummary) -> str:
    bias = " / ".join(f"{b:+.4f}" for b in s.bias_xyz_mm)
    cells = [label, f"{s.ok}/{s.frames}", f"{s.mean_mm:.4f}", f"{s.max_mm:.4f}", bias]
    cells += [f"{s.render_ms:.0f}", f"{s.localize_ms:.0f}"]
    return "| " + " | ".join(cells) + " |"


def _volume_experiment(out: Path, *, size_px: int, count: int, workers: int, **_: object) -> Experiment:
    base = Setup(camera=Camera(width_px=size_px, height_px=size_px))
    lines = [
        "## Round trip over the working volume (thesis method, one beam)",
        "",
        f"{count} tips uniform in x, y in [-2.5, 2.5] mm, z in [3, 6] mm, axis through the insertion point "
        f"{base.instrument.insertion_point_mm}; {size_px} px, 1 W, procedural retina texture, sensor noise. "
        "The first row is the thesis's section 6.3 pose: tip (3, 3, 5), beam straight down.",
        "",
        "| case | ok | mean [mm] | max [mm] | bias x / y / z [mm] | render [ms] | localize [ms] |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    summaries = []
    curves: dict[str, list[FrameResult]] = {}
    straight = [InstrumentPose([3.0, 3.0, 5.0], [0.0, 0.0, -1.0])]
    tips = working_volume_tips(count)
    volume = [InstrumentPose.through_insertion(tip, base.instrument.insertion_in_eye) for tip in tips]
    for label, blend, poses, name in (
        ("(3, 3, 5) straight down, sharp edge", 0.0, straight, "perpendicular_sharp"),
        ("volume, sharp edge (blend 0)", 0.0, volume, "volume_sharp"),
        ("volume, soft edge (blend 0.15)", 0.15, volume, "volume_soft"),
    ):
        setup = replace(base, light=Light(power_w=1.0, blend=blend))
        results = run_frames(setup, poses, "thesis", workers=workers, label=name)
        _write_frames_csv(out / f"{name}.csv", results)
        summary = summarize(results)
        summaries.append((label, summary))
        lines.append(_summary_row(label, summary))
        if len(results) > 1:
            curves[label] = results
    _plot_errors(out / "volume_errors.png", curves, f"Thesis method, working volume, {size_px} px")
    lines += [
        "",
        "![tip error per pose](volume_errors.png)",
        "",
        "A soft edge moves the Otsu edge inside the cone, so the spot looks smaller and the tip "
        "closer to the retina: the negative z bias. Section 5.5's height calibration is the thesis's answer.",
    ]
    text = "; ".join(
        f"{label}: mean {s.mean_mm:.4f} mm, max {s.max_mm:.4f} mm ({s.ok}/{s.frames} ok)" for label, s in summaries
    )
    return Experiment("volume", "\n".join(lines), text)


def _plot_errors(path: Path, curves: dict[str, list[FrameResult]], title: str) -> None:
    """Euclidean and per-axis error per pose, one row of panels per case."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(len(curves), 2, figsize=(11, 3.2 * len(curves)), squeeze=False)
    for row, (label, results) in zip(axes, curves.items(), strict=True):
        errors = np.array([r.error_mm for r in results])
        xyz = np.array([r.error_xyz_mm for r in results])
        steps = np.arange(len(results))
        row[0].bar(steps, errors, color="tab:green")
        row[0].set(title=f"{label}: |error|", xlabel="pose", ylabel="mm")
        for axis, name in enumerate("xyz"):
            row[1].plot(steps, xyz[:, axis], ".-", label=name)
        row[1].axhline(0.0, color="grey", lw=0.8)
        row[1].set(title=f"{label}: error per axis", xlabel="pose", ylabel="mm")
        row[1].legend()
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


EXPERIMENTS: dict[str, Callable[..., Experiment]] = {
    "approximation": _approximation_experiment,
    "volume": _volume_experiment,
}


def reproduce(
    out: Path,
    *,
    quick: bool = False,
    only: Sequence[str] = (),
    workers: int = 1,
    size_px: int | None = None,
    poses: int | None = None,
    log: Callable[[str], None] = print,
) -> list[Experiment]:
    """Run the experiments and write CSVs and ``report.md`` into ``out``.

    Parameters
    ----------
    out : Path
    quick : bool
        1024 px and 25 poses instead of 5000 px and 100 poses.
    only : sequence of str
        Experiment names (default: all of :data:`EXPERIMENTS`).
    workers : int
        Processes for rendering and localizing.
    size_px, poses : int, optional
        Override the image size and the number of poses per path.
    log : callable
        Receives one line per finished experiment.
    """
    unknown = sorted(set(only) - set(EXPERIMENTS))
    if unknown:
        raise ValueError(f"unknown experiment {unknown[0]!r}, allowed: {', '.join(EXPERIMENTS)}")
    out.mkdir(parents=True, exist_ok=True)
    size_px = size_px or (1024 if quick else 5000)
    count = poses or (25 if quick else 100)
    options = {"size_px": size_px, "count": count, "workers": workers}
    done = []
    for name, run in EXPERIMENTS.items():
        if only and name not in only:
            continue
        start = time.perf_counter()
        experiment = run(out, **options)
        done.append(experiment)
        log(f"{experiment.name} ({time.perf_counter() - start:.0f} s): {experiment.summary}")
    header = [
        "# spotnav reproduction of Hennerkes (2020)",
        "",
        f"Mode: {'quick' if quick else 'full'}, {size_px} px, {count} poses per path. "
        "Regenerate with `spotnav reproduce" + (" --quick" if quick else "") + "`.",
        "",
        "",
    ]
    (out / "report.md").write_text("\n".join(header) + "\n\n".join(e.markdown for e in done) + "\n", encoding="utf-8")
    return done
