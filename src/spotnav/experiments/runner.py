"""Render known poses, localize them and measure the error, across worker processes.

Frames are seeded per pose, so results do not depend on the number of workers.
Each worker keeps its renderer's static images between jobs of the same world.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import numpy as np

from spotnav.app.progress import progress
from spotnav.experiments.frame import localize_timed, render_timed, run_timed_frame
from spotnav.optics.render import Renderer
from spotnav.pose.estimate import PoseEstimate, within_sigmas
from spotnav.pose.thesis import fit_height_correction
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose, angles_between, axis_rotations

__all__ = [
    "ErrorSummary",
    "FrameJob",
    "FrameResult",
    "FrameRunner",
    "Variant",
    "calibrate_height",
    "count_refusals",
    "error_cells",
    "localize_variants",
    "render_frame",
    "run_frame",
    "run_frames",
    "summarize",
]


@dataclass(frozen=True)
class Variant:
    """One way to localize a rendered frame.

    Attributes
    ----------
    label : str
        Column name in reports.
    setup : Setup
        The localizer's setup (it may differ from the rendered world).
    method : str
        A :data:`spotnav.pose.localize.METHODS` name.
    """

    label: str
    setup: Setup
    method: str = "thesis"


@dataclass(frozen=True)
class FrameJob:
    """Render ``pose`` in ``world`` with noise ``seed`` and localize it with each variant."""

    world: Setup
    pose: InstrumentPose
    seed: int
    variants: tuple[Variant, ...]


@dataclass(frozen=True)
class FrameResult:
    """One rendered frame localized by one variant.

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
        error: np.ndarray = self.estimate.tip_in_eye - self.truth.tip_in_eye
        return error

    @property
    def error_mm(self) -> float:
        """Euclidean tip error, mm; NaN unless ``ok``."""
        return float(np.linalg.norm(self.error_xyz_mm))

    @property
    def rotation_error_deg(self) -> np.ndarray:
        """Absolute error of the axis's rotation about y and about z, and the angle between axes.

        Shape (3,), degrees (see :func:`spotnav.setup.geometry.axis_rotations`); NaN unless ``ok``.
        """
        if self.estimate.axis is None:
            return np.full(3, np.nan)
        difference = axis_rotations(self.estimate.axis) - axis_rotations(self.truth.axis)
        wrapped = np.abs((difference + np.pi) % (2 * np.pi) - np.pi)
        return np.degrees([*wrapped, angles_between(self.estimate.axis, self.truth.axis)])


@dataclass(frozen=True)
class ErrorSummary:
    """Accuracy over a set of frames (``ok`` frames only).

    Attributes
    ----------
    frames, ok : int
    mean_mm, max_mm : float
        Euclidean tip error.
    bias_xyz_mm : ndarray, shape (3,)
        Mean signed error per axis.
    rotation_mean_deg, rotation_max_deg : ndarray, shape (3,)
        About y, about z, and the angle between axes.
    render_ms, localize_ms : float
        Medians.
    within_3_sigma : float
        Fraction of the ``ok`` frames whose 3-D error is within 3 of its 3-D standard error
        (:func:`spotnav.pose.estimate.within_sigmas`; NaN without sigmas).
    sigma_median_mm : float
        Median reported 1-sigma tip uncertainty (NaN without sigmas).
    refusals : str
        The statuses of the frames without a pose, with their counts (:func:`count_refusals`; ``-``: none).
    """

    frames: int
    ok: int
    mean_mm: float
    max_mm: float
    bias_xyz_mm: np.ndarray
    rotation_mean_deg: np.ndarray
    rotation_max_deg: np.ndarray
    render_ms: float
    localize_ms: float
    within_3_sigma: float
    sigma_median_mm: float
    refusals: str = "-"

    @property
    def why_none(self) -> str:
        """Why these frames have no error to report: ``no ok frame: 0/3; mismatch 3``."""
        refused = f"; {self.refusals}" if self.refusals != "-" else ""
        return f"no ok frame: {self.ok}/{self.frames}{refused}"

    def text(self, value: float, spec: str = ".4f") -> str:
        """One of these frames' figures as ``spec`` formats it, or ``-`` and why it is missing: no ``ok`` frame, or
        (a sigma's figure) no ``ok`` frame that reported a sigma."""
        if np.isfinite(value):
            return format(value, spec)
        return f"- ({self.why_none if not self.ok else 'no ok frame reported a sigma'})"

    @property
    def within_3_sigma_text(self) -> str:
        """:attr:`within_3_sigma` in per cent (``92 %``), or ``-`` and why."""
        return self.text(100 * self.within_3_sigma, ".0f") + (" %" if np.isfinite(self.within_3_sigma) else "")


def summarize(results: Sequence[FrameResult]) -> ErrorSummary:
    """Mean and max tip and rotation errors, bias and median timings."""
    errors = np.array([r.error_mm for r in results])
    ok = np.isfinite(errors)
    xyz = np.array([r.error_xyz_mm for r in results]).reshape(-1, 3)[ok]
    rotations = np.array([r.rotation_error_deg for r in results]).reshape(-1, 3)[ok]
    nan3, nan = np.full(3, np.nan), float("nan")
    sigmas = np.array([r.estimate.sigma_mm for r in results])
    with_sigma = ok & np.isfinite(sigmas)
    return ErrorSummary(
        frames=len(results),
        ok=int(ok.sum()),
        mean_mm=float(errors[ok].mean()) if ok.any() else float("nan"),
        max_mm=float(errors[ok].max()) if ok.any() else float("nan"),
        bias_xyz_mm=xyz.mean(axis=0) if ok.any() else nan3,
        rotation_mean_deg=rotations.mean(axis=0) if ok.any() else nan3,
        rotation_max_deg=rotations.max(axis=0) if ok.any() else nan3,
        render_ms=float(np.median([r.render_ms for r in results])),
        localize_ms=float(np.median([r.localize_ms for r in results])),
        within_3_sigma=float(within_sigmas(errors[with_sigma], sigmas[with_sigma]).mean()) if with_sigma.any() else nan,
        sigma_median_mm=float(np.median(sigmas[with_sigma])) if with_sigma.any() else nan,
        refusals=count_refusals(results),
    )


def count_refusals(results: Sequence[FrameResult]) -> str:
    """The statuses of the frames without a pose, each with its count (``"blurred 3, unreliable 1"``; ``-``: none)."""
    statuses = [r.estimate.status for r in results if not r.estimate.ok]
    return ", ".join(f"{s} {statuses.count(s)}" for s in sorted(set(statuses))) or "-"


def error_cells(summary: ErrorSummary) -> list[str]:
    """A report's mean and max tip error (mm, 4 decimals) and share within 3 sigma (per cent); ``-`` and why where
    there is none (:meth:`ErrorSummary.text`)."""
    return [summary.text(summary.mean_mm), summary.text(summary.max_mm), summary.within_3_sigma_text]


def run_frame(job: FrameJob) -> tuple[FrameResult, ...]:
    """Render one job's frame and localize it with each of its variants (:func:`run_timed_frame`)."""
    localizers = [(variant.setup, variant.method) for variant in job.variants]
    frame = run_timed_frame(Renderer(job.world), job.pose, job.seed, localizers)
    return tuple(
        FrameResult(job.pose, estimate, frame.render_ms, localize_ms)
        for estimate, localize_ms in zip(frame.estimates, frame.localize_ms, strict=True)
    )


def localize_variants(
    image: np.ndarray, job: FrameJob, render_ms: float, variants: Sequence[Variant]
) -> tuple[FrameResult, ...]:
    """Localize a rendered frame of ``job`` with each of ``variants``, timed."""
    results = []
    for variant in variants:
        estimate, localize_ms = localize_timed(image, variant.setup, variant.method)
        results.append(FrameResult(job.pose, estimate, render_ms, localize_ms))
    return tuple(results)


def calibrate_height(job: FrameJob) -> float:
    """Section 5.5: render the job's pose and fit the height factor of its first variant's setup.

    NaN when the frame shows no usable spot or the factor leaves the setup's range [0.5, 2].
    """
    image = render_frame(job)
    fitted = fit_height_correction(image, job.variants[0].setup, job.pose.tip_in_eye)
    if not fitted.ok:
        return float("nan")
    factor = fitted.factor
    return factor if 0.5 <= factor <= 2.0 else float("nan")


def render_frame(job: FrameJob) -> np.ndarray:
    """Render the job's frame only."""
    return render_timed(Renderer(job.world), job.pose, job.seed)[0]


class FrameRunner:
    """Run jobs in this process (``workers = 1``) or in a pool of processes, with a progress bar.

    Use as a context manager so that the pool is shut down.
    """

    def __init__(self, workers: int = 1) -> None:
        if workers < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        self.workers = workers
        self._pool = ProcessPoolExecutor(workers) if workers > 1 else None

    def __enter__(self) -> FrameRunner:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)

    def map(self, function: Callable[[FrameJob], Any], jobs: Sequence[FrameJob], label: str) -> list[Any]:
        """``[function(job) for job in jobs]``, in order, with a progress bar named ``label``."""
        bar = progress(total=len(jobs), desc=label, unit="frame", leave=False)
        try:
            if self._pool is None:
                outputs: Iterable[Any] = map(function, jobs)
            else:
                outputs = self._pool.map(function, jobs, chunksize=max(1, len(jobs) // (8 * self.workers)))
            results = []
            for output in outputs:
                results.append(output)
                bar.update()
            return results
        finally:
            bar.close()


def run_frames(
    setup: Setup,
    poses: Sequence[InstrumentPose],
    method: str = "thesis",
    *,
    seed: int = 0,
    workers: int = 1,
    label: str = "frames",
) -> list[FrameResult]:
    """Render and localize every pose in ``setup``'s world; frame ``i`` uses noise seed ``seed + i``."""
    variant = (Variant(method, setup, method),)
    jobs = [FrameJob(setup, pose, seed + i, variant) for i, pose in enumerate(poses)]
    with FrameRunner(workers) as runner:
        return [results[0] for results in runner.map(run_frame, jobs, label)]
