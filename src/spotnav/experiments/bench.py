"""Speed benchmark: ms per frame of rendering, the full-frame methods and tracking, per image size."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from spotnav.experiments.chapter6 import thesis_world, with_true_edge
from spotnav.experiments.paths import helix_tips, poses_through_insertion
from spotnav.localize import localize
from spotnav.render import Renderer
from spotnav.track import Tracker

__all__ = ["STAGES", "BenchRow", "bench_markdown", "run_bench"]

STAGES = (
    "render",
    "thesis, full frame",
    "precise, full frame",
    "tracking (region of interest)",
    "tracking, frames from memory",
)
HELIX_FRAMES = 300  # the helix's motion per frame: that of a 300-frame helix


@dataclass(frozen=True)
class BenchRow:
    """Timing of one stage at one image size.

    Attributes
    ----------
    size_px : int
    stage : str
        One of :data:`STAGES`.
    median_ms, p99_ms : float
        Median and 99th percentile, ms per frame.
    frames : int
        Frames timed.
    """

    size_px: int
    stage: str
    median_ms: float
    p99_ms: float
    frames: int


def _ms_since(start: float) -> float:
    return 1000 * (time.perf_counter() - start)


def _time_tracking(tracker: Tracker, image: np.ndarray, times: list[float]) -> None:
    """Track ``image``, adding its time to ``times`` if it was tracked (not an acquisition)."""
    start = time.perf_counter()
    tracked = tracker.update(image)
    if tracked.mode == "tracked":
        times.append(_ms_since(start))


def run_bench(
    sizes: Sequence[int], frames: int = 100, beams: int = 1, full_every: int = 5, memory_mb: float = 4096.0
) -> list[BenchRow]:
    """Time each stage on consecutive frames of the helix, in this process.

    Every frame is rendered and tracked; every ``full_every``-th frame is also
    localized on the whole image by the thesis's and the precise method.
    Tracking is timed on the frames it tracked (not the acquisitions), twice:
    right after each frame's rendering, which leaves the caches cold (as
    decoding a video does), and then once more over the same frames kept in
    memory, back to back, as a camera hands them over (the first frames that
    fit in ``memory_mb``).
    """
    if frames < 2 or full_every < 1 or memory_mb < 0:
        raise ValueError(
            f"frames must be >= 2, full_every >= 1 and memory_mb >= 0, got {frames}, {full_every} and {memory_mb}"
        )
    rows = []
    for size in sizes:
        setup = thesis_world(size, beams)
        localizer = with_true_edge(setup)  # the simulation knows its geometry
        renderer, tracker = Renderer(setup), Tracker(localizer)
        renderer.render(poses_through_insertion(helix_tips(2), setup.instrument.insertion_in_eye)[0])  # warm caches
        times: dict[str, list[float]] = {stage: [] for stage in STAGES}
        poses = poses_through_insertion(helix_tips(HELIX_FRAMES)[:frames], setup.instrument.insertion_in_eye)
        kept: list[np.ndarray] = []
        for index, pose in enumerate(tqdm(poses, desc=f"bench {size} px", unit="frame", disable=None)):
            start = time.perf_counter()
            image = renderer.render(pose, seed=index)
            times["render"].append(_ms_since(start))
            if index % full_every == 0:
                for stage, method in ((STAGES[1], "thesis"), (STAGES[2], "precise")):
                    start = time.perf_counter()
                    localize(image, localizer, method)
                    times[stage].append(_ms_since(start))
            _time_tracking(tracker, image, times[STAGES[3]])
            if (len(kept) + 1) * image.nbytes <= memory_mb * 2**20:
                kept.append(image)
        tracker = Tracker(localizer)
        for image in kept:
            _time_tracking(tracker, image, times[STAGES[4]])
        for stage, values in times.items():
            if values:
                median, p99 = float(np.median(values)), float(np.percentile(values, 99))
                rows.append(BenchRow(size, stage, median, p99, len(values)))
    return rows


def bench_markdown(rows: Sequence[BenchRow]) -> str:
    """The rows as a markdown table, with tracking's ratio to the thesis method's full frame."""
    lines = ["| size px | stage | median ms | p99 ms | frames |", "| --- | --- | --- | --- | --- |"]
    lines += [f"| {r.size_px} | {r.stage} | {r.median_ms:.2f} | {r.p99_ms:.2f} | {r.frames} |" for r in rows]
    by_key = {(r.size_px, r.stage): r for r in rows}
    for size in sorted({r.size_px for r in rows}):
        thesis, tracking = by_key.get((size, STAGES[1])), by_key.get((size, STAGES[3]))
        if thesis and tracking:
            lines.append(
                f"\n{size} px: tracking takes {tracking.median_ms / thesis.median_ms:.3f} of the thesis method's "
                f"full-frame time ({1000 / tracking.median_ms:.0f} Hz)."
            )
    return "\n".join(lines)
