"""Speed benchmark: ms per frame of rendering, the full-frame methods, tracking and re-acquisition, per image size.

:func:`run_bench` times each stage on the helix; :func:`run_stress` tracks a
helix whose spot is hidden every few frames, so that re-acquisitions are
frequent, and reports every frame's time with the accuracy kept.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from spotnav.app.paths import path_poses
from spotnav.app.progress import progress
from spotnav.app.track import Tracker, frozen_heap
from spotnav.experiments.faults import SILENT_ERROR_MM
from spotnav.experiments.frame import localize_timed, render_timed
from spotnav.experiments.scenes import thesis_world, with_true_edge
from spotnav.optics.render import Renderer
from spotnav.setup.config import Setup

__all__ = ["STAGES", "BenchRow", "StressResult", "bench_markdown", "run_bench", "run_stress", "stress_markdown"]

# Cameras' frame periods: one at 1000 frame/s (a 1 kHz control loop) and a slower one at 100. Between frames the
# tracker waits, and its caches cool: the longer, the more.
CAMERA_PERIODS_S = (0.001, 0.01)
_CAMERA_STAGES = tuple(f"tracking, a frame every {1000 * period:.0f} ms" for period in CAMERA_PERIODS_S)
STAGES = (
    "render",
    "thesis, full frame",
    "acquisition (precise, full frame)",
    "tracking (region of interest)",
    "tracking, frames from memory",
    *_CAMERA_STAGES,
    "re-acquisition after a loss",
)
HELIX_FRAMES = 300  # the helix's motion per frame: that of a 300-frame helix
_FOUND_AGAIN = ("reacquired", "acquired")  # a frame after a loss with a pose: where last seen, or the whole image
LOSS_EVERY = 10  # the re-acquisition stage loses the spot (a dark frame) once in this many frames, from the 6th


@dataclass(frozen=True)
class BenchRow:
    """Timing of one stage at one image size.

    Attributes
    ----------
    size_px : int
    stage : str
        One of :data:`STAGES`.
    median_ms, p99_ms, max_ms : float
        Median, 99th percentile and slowest, ms per frame.
    frames : int
        Frames timed.
    """

    size_px: int
    stage: str
    median_ms: float
    p99_ms: float
    max_ms: float
    frames: int

    @classmethod
    def of_times(cls, size_px: int, stage: str, times_ms: Sequence[float]) -> BenchRow:
        """The row of ``times_ms`` (at least one)."""
        values = np.asarray(times_ms, dtype=float)
        return cls(
            size_px, stage, float(np.median(values)), float(np.percentile(values, 99)), float(values.max()), len(values)
        )


def _ms_since(start: float) -> float:
    return 1000 * (time.perf_counter() - start)


def _time_tracking(tracker: Tracker, image: np.ndarray, times: list[float]) -> None:
    """Track ``image``, adding its time to ``times`` if it was tracked (not an acquisition)."""
    start = time.perf_counter()
    tracked = tracker.update(image)
    if tracked.mode == "tracked":
        times.append(_ms_since(start))


def _fastest_passes(setup: Setup, images: Sequence[np.ndarray], passes: int) -> list[float]:
    """Each of ``images``' fastest time over ``passes`` passes of a new :class:`Tracker`, ms; only the frames every
    pass tracked."""
    times = np.full((passes, len(images)), np.nan)
    for row in times:
        tracker = Tracker(setup)
        for index, image in enumerate(images):
            start = time.perf_counter()
            if tracker.update(image).mode == "tracked":
                row[index] = _ms_since(start)
    tracked = np.all(np.isfinite(times), axis=0)
    return [float(value) for value in np.min(times[:, tracked], axis=0)]


def _time_full_frame(setup: Setup, image: np.ndarray, times: dict[str, list[float]]) -> None:
    """Localize ``image`` on the whole image by the thesis's and the precise method, adding each one's time."""
    for stage, method in ((STAGES[1], "thesis"), (STAGES[2], "precise")):
        times[stage].append(localize_timed(image, setup, method)[1])


def run_bench(
    sizes: Sequence[int],
    frames: int = 100,
    beams: int = 1,
    full_every: int = 5,
    memory_mb: float = 4096.0,
    passes: int = 1,
) -> list[BenchRow]:
    """Time each stage on consecutive frames of the helix, in this process.

    Every frame is rendered and tracked. Tracking is timed on the frames it
    tracked (not the acquisitions), four times: right after each frame's
    rendering, which leaves the caches cold (as decoding a video does); over
    the same frames kept in memory (the first frames that fit in
    ``memory_mb``), back to back, as a camera at the tracker's own rate hands
    them over (``passes`` times, each with a new tracker, each frame timed
    by its fastest pass: on a shared machine, other work slows some passes);
    and over those frames again for each of
    ``CAMERA_PERIODS_S``, each frame handed over that period after the one
    before (or after the tracker is done with it, if later), as a camera of
    that rate would: the tracker waits, and meets each frame with cooler
    caches.
    Every ``full_every``-th frame is also localized on the whole image by the
    thesis's and the precise method, both in the same conditions: on its copy
    in memory (right after rendering, the first method to read a frame paid
    for the renderer's memory: the thesis method's time tripled at 2048 px),
    or, past ``memory_mb``, right after rendering.
    A last pass over the frames in memory loses the spot (a dark frame) once
    every ``LOSS_EVERY`` frames, from the sixth, and times the frame that
    finds it again.
    """
    if frames < 2 or full_every < 1 or memory_mb < 0 or passes < 1:
        raise ValueError(
            f"frames must be >= 2, full_every >= 1, memory_mb >= 0 and passes >= 1, got {frames}, {full_every}, "
            f"{memory_mb} and {passes}"
        )
    rows = []
    with frozen_heap():  # as a real-time loop runs (spotnav track)
        for size in sizes:
            setup = thesis_world(size, beams)
            localizer = with_true_edge(setup)  # the simulation knows its geometry
            renderer, tracker = Renderer(setup), Tracker(localizer)
            renderer.render(path_poses("helix", 2, setup.instrument.insertion_in_eye)[0])  # warm caches
            times: dict[str, list[float]] = {stage: [] for stage in STAGES}
            poses = path_poses("helix", HELIX_FRAMES, setup.instrument.insertion_in_eye)[:frames]
            kept: list[np.ndarray] = []
            for index, pose in enumerate(progress(poses, desc=f"bench {size} px", unit="frame")):
                image, render_ms = render_timed(renderer, pose, index)
                times["render"].append(render_ms)
                _time_tracking(tracker, image, times[STAGES[3]])
                if (len(kept) + 1) * image.nbytes <= memory_mb * 2**20:
                    kept.append(image)
                elif index % full_every == 0:
                    _time_full_frame(localizer, image, times)
            for image in kept[::full_every]:
                _time_full_frame(localizer, image, times)
            times[STAGES[4]] = _fastest_passes(localizer, kept, passes)
            for period, stage in zip(CAMERA_PERIODS_S, _CAMERA_STAGES, strict=True):
                tracker, due = Tracker(localizer), time.perf_counter()
                for image in kept:
                    due = max(due, time.perf_counter()) + period
                    time.sleep(max(due - time.perf_counter(), 0.0))
                    _time_tracking(tracker, image, times[stage])
            tracker = Tracker(localizer)
            for index, image in enumerate(kept):
                if index % LOSS_EVERY == LOSS_EVERY // 2:
                    tracker.update(np.zeros_like(image))
                    start = time.perf_counter()
                    if tracker.update(image).mode in _FOUND_AGAIN:
                        times[STAGES[-1]].append(_ms_since(start))
                else:
                    tracker.update(image)
            rows += [BenchRow.of_times(size, stage, values) for stage, values in times.items() if values]
    return rows


def bench_markdown(rows: Sequence[BenchRow]) -> str:
    """The rows as a markdown table, with each stage's median as a ratio to the thesis method's full frame."""
    lines = [
        "| size px | stage | median ms | p99 ms | max ms | frames | median / thesis |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    by_key = {(r.size_px, r.stage): r for r in rows}
    for r in rows:
        thesis = by_key.get((r.size_px, STAGES[1]))
        ratio = f"{r.median_ms / thesis.median_ms:.3f}" if thesis and r.stage != STAGES[0] else ""
        lines.append(
            f"| {r.size_px} | {r.stage} | {r.median_ms:.2f} | {r.p99_ms:.2f} | {r.max_ms:.2f} | {r.frames} | {ratio} |"
        )
    for size in sorted({r.size_px for r in rows}):
        thesis, tracking = by_key.get((size, STAGES[1])), by_key.get((size, STAGES[3]))
        if thesis and tracking:
            lines.append(
                f"\n{size} px: tracking takes {tracking.median_ms / thesis.median_ms:.3f} of the thesis method's "
                f"full-frame time ({1000 / tracking.median_ms:.0f} Hz)."
            )
    return "\n".join(lines)


@dataclass(frozen=True)
class StressResult:
    """Tracking a helix whose spot is hidden every few frames, at one image size.

    Attributes
    ----------
    size_px : int
    frames : int
        Frames tracked, the hidden ones included.
    hidden : int
        Frames whose spot was hidden (a dark frame).
    reacquired : int
        Frames that found the spot again after a loss ...
    nearby : int
        ... of them where it was last seen (the others on the whole image).
    first_ms : float
        The first frame's time: an acquisition on the whole image.
    all_frames : BenchRow
        The time of every frame after the first.
    reacquisitions : BenchRow or None
        The re-acquisitions' times.
    ok : int
        Frames with a pose.
    mean_mm, max_mm : float
        Tip error over the frames with a pose.
    silent : int
        Frames with a pose more than :data:`~spotnav.experiments.faults.SILENT_ERROR_MM` off, or any pose
        on a dark frame.
    slowest : tuple of (int, str)
        The slowest frame after the first: its index and how the tracker answered it
        (:data:`~spotnav.app.track.TRACK_MODES`).
    """

    size_px: int
    frames: int
    hidden: int
    reacquired: int
    nearby: int
    first_ms: float
    all_frames: BenchRow
    reacquisitions: BenchRow | None
    ok: int
    mean_mm: float
    max_mm: float
    silent: int
    slowest: tuple[int, str]


def run_stress(size: int, frames: int = 300, hide_every: int = 8, beams: int = 1) -> StressResult:
    """Track ``frames`` consecutive helix frames (a 300-frame helix's motion), every ``hide_every``-th one dark.

    Each frame is rendered just before it is tracked (caches cold, as when
    decoding a video); only :meth:`Tracker.update` is timed. The frame after
    a dark one is re-acquired (where the spot was last seen, else on the
    whole image). The first frame, an acquisition on the whole image, is
    timed apart (``first_ms``).
    """
    if frames < 2 or hide_every < 2:
        raise ValueError(f"frames and hide_every must be >= 2, got {frames} and {hide_every}")
    setup = thesis_world(size, beams)
    localizer = with_true_edge(setup)
    renderer, tracker = Renderer(setup), Tracker(localizer)
    poses = path_poses("helix", max(frames, HELIX_FRAMES), setup.instrument.insertion_in_eye)[:frames]
    renderer.render(poses[0])  # warm caches
    times, modes, reacquisitions, errors, hidden, ghosts, nearby = [], [], [], [], 0, 0, 0
    was_lost = False
    with frozen_heap():  # as a real-time loop runs (spotnav track)
        for index, pose in enumerate(progress(poses, desc=f"stress {size} px", unit="frame")):
            image = render_timed(renderer, pose, index)[0]
            dark = index % hide_every == hide_every - 1
            if dark:
                image, hidden = np.zeros_like(image), hidden + 1
            start = time.perf_counter()
            tracked = tracker.update(image)
            times.append(_ms_since(start))
            modes.append(tracked.mode)
            if was_lost and tracked.mode in _FOUND_AGAIN:
                reacquisitions.append(times[-1])
                nearby += tracked.mode == "reacquired"
            was_lost = tracked.mode == "lost"
            if tracked.estimate.ok and dark:
                ghosts += 1
            elif tracked.estimate.ok:
                errors.append(float(np.linalg.norm(tracked.estimate.tip_in_eye - pose.tip_in_eye)))
    values = np.asarray(errors) if errors else np.array([np.nan])
    slowest = 1 + int(np.argmax(times[1:]))
    return StressResult(
        size,
        frames,
        hidden,
        len(reacquisitions),
        nearby,
        times[0],
        BenchRow.of_times(size, "every frame after the first", times[1:]),
        BenchRow.of_times(size, "re-acquisition", reacquisitions) if reacquisitions else None,
        len(errors) + ghosts,
        float(values.mean()),
        float(values.max()),
        int(np.sum(values > SILENT_ERROR_MM)) + ghosts,
        (slowest, modes[slowest]),
    )


def stress_markdown(results: Sequence[StressResult]) -> str:
    """The stress runs as a markdown table."""
    lines = [
        "| size px | frames | hidden | re-acquired | where last seen | ok | first ms | median ms | p99 ms | max ms "
        "| re-acquisition median ms | re-acquisition max ms | mean mm | max mm | silent failures |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in results:
        every, again = r.all_frames, r.reacquisitions
        median, slowest = (again.median_ms, again.max_ms) if again else (float("nan"), float("nan"))
        lines.append(
            f"| {r.size_px} | {r.frames} | {r.hidden} | {r.reacquired} | {r.nearby} | {r.ok} | {r.first_ms:.2f} "
            f"| {every.median_ms:.2f} | {every.p99_ms:.2f} | {every.max_ms:.2f} | {median:.2f} | {slowest:.2f} "
            f"| {r.mean_mm:.4f} | {r.max_mm:.4f} | {r.silent} |"
        )
    slowest_frames = [f"{r.size_px} px: frame {r.slowest[0]} ({r.slowest[1]})" for r in results]
    return "\n".join(
        [
            *lines,
            "",
            "median, p99 and max: every frame after the first (an acquisition on the whole image)",
            f"the slowest: {'; '.join(slowest_frames)}",
        ]
    )
