"""Where a frame's time goes: the whole-frame acquisition and a tracked frame, profiled function by function.

:func:`run_profile` profiles (:mod:`cProfile`) the precise method on whole frames of the helix, each right after
the thesis method (as ``spotnav bench`` times it), and the tracked frames of the same helix from memory. Each
function's own time goes to one of :data:`PARTS`: spotnav's compiled kernels (Numba), OpenCV, or the rest: Python,
NumPy, and the profiler's own cost of about a microsecond a call, which the rest's figure includes.
"""

from __future__ import annotations

import cProfile
import pstats
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import cv2
import numpy as np
from numba.core.registry import CPUDispatcher

from spotnav.app import track
from spotnav.app.paths import path_poses
from spotnav.app.progress import progress
from spotnav.app.track import Tracker, frozen_heap
from spotnav.experiments.bench import HELIX_FRAMES, STAGES
from spotnav.experiments.frame import localize_timed, render_timed
from spotnav.experiments.scenes import thesis_world, with_true_edge
from spotnav.optics.render import Renderer
from spotnav.pose import pipeline, precise
from spotnav.pose.localize import localize

__all__ = ["PARTS", "PROFILED_STAGES", "FunctionTime", "StageProfile", "profile_markdown", "run_profile"]

PARTS = ("compiled (Numba)", "OpenCV", "Python, NumPy and the profiler")
PROFILED_STAGES = (STAGES[2], STAGES[4])  # the acquisition, right after the thesis method; tracked frames from memory
# Each stage's steps, in order: the function that runs each one, its callees' time included.
_STEPS: dict[str, tuple[tuple[str, Callable[..., object]], ...]] = {
    PROFILED_STAGES[0]: (
        ("detection", precise.detect_spots),
        ("find: thesis start, beams, rays", precise.plan_spots),
        ("read the light", pipeline.read_light),
        ("fit, shaft and judge", precise._fit_precise),
    ),
    PROFILED_STAGES[1]: (
        ("find: predicted rays", track._plan_predicted),
        ("read the light", pipeline.read_light),
        ("fit, shaft and judge", track._fit_read_edges),
    ),
}
_Result = TypeVar("_Result")


@dataclass(frozen=True)
class FunctionTime:
    """One function's own time in a stage.

    Attributes
    ----------
    name : str
        ``module.function`` (``cv2.GaussianBlur`` for OpenCV's).
    part : str
        One of :data:`PARTS`.
    ms : float
        Its own time (not its callees'), ms per frame.
    calls : float
        Calls per frame.
    """

    name: str
    part: str
    ms: float
    calls: float


@dataclass(frozen=True)
class StageProfile:
    """Where one stage's time goes at one image size.

    Attributes
    ----------
    size_px : int
    stage : str
        One of :data:`PROFILED_STAGES`.
    frames : int
        Frames profiled.
    total_ms : float
        Its time per frame, profiled (the profiler's cost included).
    parts_ms : tuple of float
        Each of :data:`PARTS`' own time, ms per frame.
    steps_ms : tuple of (str, float)
        Each step of the stage and its time (its callees' included), ms per frame.
    calls : float
        Function calls per frame.
    functions : tuple of FunctionTime
        The functions with the most own time, most first.
    """

    size_px: int
    stage: str
    frames: int
    total_ms: float
    parts_ms: tuple[float, ...]
    steps_ms: tuple[tuple[str, float], ...]
    calls: float
    functions: tuple[FunctionTime, ...]


def _key(function: Callable[..., object]) -> tuple[str, int, str]:
    """The profiler's key of a Python function: its file, first line and name."""
    code = function.__code__
    return code.co_filename, code.co_firstlineno, code.co_name


def _compiled_kernels() -> set[tuple[str, int, str]]:
    """The profiler's keys of spotnav's compiled kernels, in the modules loaded."""
    kernels = set()
    for name, module in list(sys.modules.items()):
        if name == "spotnav" or name.startswith("spotnav."):
            kernels |= {_key(value.py_func) for value in vars(module).values() if isinstance(value, CPUDispatcher)}
    return kernels


def _function_times(stats: pstats.Stats, frames: int, top: int) -> tuple[tuple[float, ...], float, list[FunctionTime]]:
    """Each part's own time and the calls, per frame, and the ``top`` functions with the most own time."""
    kernels, opencv = _compiled_kernels(), set(dir(cv2))
    parts, calls, functions = dict.fromkeys(PARTS, 0.0), 0.0, []
    entries = stats.stats.items()  # type: ignore[attr-defined]  # typeshed's pstats.Stats omits .stats (pstats docs)
    for (file, line, name), (_, count, own_s, _, _) in entries:
        if (file, line, name) in kernels:
            part, label = PARTS[0], f"{Path(file).stem}.{name}"
        elif file == "~" and name.strip("<>") in opencv:
            part, label = PARTS[1], f"cv2.{name.strip('<>')}"
        else:
            part, label = PARTS[2], name if file == "~" else f"{Path(file).stem}.{name}"
        parts[part] += 1000 * own_s / frames
        calls += count / frames
        functions.append(FunctionTime(label, part, 1000 * own_s / frames, count / frames))
    functions.sort(key=lambda f: -f.ms)
    return tuple(parts.values()), calls, functions[:top]


def _stage_profile(
    size: int, stage: str, profiles: list[cProfile.Profile], times_ms: list[float], top: int
) -> StageProfile:
    """The stage's profile over its frames' ``profiles`` and their profiled times (ms)."""
    stats = pstats.Stats(profiles[0])
    for profile in profiles[1:]:
        stats.add(profile)
    parts, calls, functions = _function_times(stats, len(profiles), top)
    steps = []
    for step, function in _STEPS[stage]:
        timing = stats.stats.get(_key(function))  # type: ignore[attr-defined]  # typeshed's pstats.Stats omits .stats
        steps.append((step, 0.0 if timing is None else 1000 * timing[3] / len(profiles)))
    return StageProfile(
        size, stage, len(profiles), float(np.mean(times_ms)), parts, tuple(steps), calls, tuple(functions)
    )


def _profiled(call: Callable[..., _Result], *args: object) -> tuple[_Result, cProfile.Profile, float]:
    """``call(*args)`` profiled: its result, its profile and its time (ms)."""
    profile = cProfile.Profile()
    start = time.perf_counter()
    profile.enable()
    result = call(*args)
    profile.disable()
    return result, profile, 1000 * (time.perf_counter() - start)


def run_profile(sizes: Sequence[int], frames: int = 40, beams: int = 1, top: int = 12) -> list[StageProfile]:
    """Profile the acquisition and the tracked frames on ``frames`` consecutive helix frames per size.

    The frames are rendered first and kept in memory. Each is localized on
    the whole image by the thesis method, then profiled while the precise
    method localizes it (the acquisition, as ``spotnav bench`` times it:
    right after the thesis method, whose passes over the frame evict the
    caches). A tracker then runs over the frames; the frames it tracked
    (not its acquisitions) are profiled. A stage with no frame profiled is
    left out.
    """
    if frames < 2 or top < 1:
        raise ValueError(f"frames must be >= 2 and top >= 1, got {frames} and {top}")
    results = []
    with frozen_heap():  # as a real-time loop runs (spotnav track)
        for size in sizes:
            setup = thesis_world(size, beams)
            localizer = with_true_edge(setup)  # the simulation knows its geometry
            renderer = Renderer(setup)
            poses = path_poses("helix", HELIX_FRAMES, setup.instrument.insertion_in_eye)[:frames]
            images = [render_timed(renderer, pose, index)[0] for index, pose in enumerate(poses)]
            tracker = Tracker(localizer)  # compiles (or loads) the kernels first
            acquired: tuple[list[cProfile.Profile], list[float]] = ([], [])
            for image in progress(images, desc=f"profile {size} px", unit="frame"):
                localize_timed(image, localizer, "thesis")  # as spotnav bench times it, before the precise method
                _, profile, elapsed = _profiled(localize, image, localizer, "precise")
                acquired[0].append(profile)
                acquired[1].append(elapsed)
            tracked: tuple[list[cProfile.Profile], list[float]] = ([], [])
            for image in images:
                answer, profile, elapsed = _profiled(tracker.update, image)
                if answer.mode == "tracked":
                    tracked[0].append(profile)
                    tracked[1].append(elapsed)
            for stage, (profiles, times) in zip(PROFILED_STAGES, (acquired, tracked), strict=True):
                if profiles:
                    results.append(_stage_profile(size, stage, profiles, times, top))
    return results


def profile_markdown(profiles: Sequence[StageProfile]) -> str:
    """Each stage's parts and busiest functions as markdown tables."""
    blocks = []
    for p in profiles:
        lines = [
            f"## {p.size_px} px, {p.stage}: {p.total_ms:.2f} ms a frame profiled, {p.calls:.0f} calls "
            f"({p.frames} frames)",
            "",
            "| part | ms per frame | share |",
            "| --- | --- | --- |",
        ]
        total = max(sum(p.parts_ms), 1e-12)
        lines += [
            f"| {part} | {ms:.3f} | {100 * ms / total:.0f} % |" for part, ms in zip(PARTS, p.parts_ms, strict=True)
        ]
        lines += ["", "| step | ms per frame |", "| --- | --- |"]
        lines += [f"| {step} | {ms:.3f} |" for step, ms in p.steps_ms]
        lines += ["", "| function (own time) | part | ms per frame | calls per frame |", "| --- | --- | --- | --- |"]
        lines += [f"| {f.name} | {f.part} | {f.ms:.3f} | {f.calls:.1f} |" for f in p.functions]
        blocks.append("\n".join(lines))
    return "\n\n".join(blocks)
