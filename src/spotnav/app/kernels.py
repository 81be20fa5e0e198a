"""Every command's compiled kernels at once: :func:`warm_kernels`, and whether Numba's cache holds them.

Numba compiles a kernel on its first call and caches it (beside the sources, or under ``NUMBA_CACHE_DIR``). Left
to itself, each command would compile what it meets, piecemeal and silently: ``localize`` the frame's, ``calibrate``
a dozen more. :func:`warm_kernels` runs every command's kernels on small synthetic frames instead (a few tasks,
split over the cores in processes, so that they compile in parallel) and marks the cache done;
:func:`kernels_compiled` reads that mark. ``spotnav/__init__`` drops the kernels cached beside the sources when any
source changes, and the mark names the sources it was made for, so the next command compiles them again.
``python -m spotnav.app.kernels`` warms the cache (``make run`` and ``make test`` do).
"""

from __future__ import annotations

import hashlib
import multiprocessing
import os
import platform
import signal
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

import numba
import numpy as np

import spotnav
from spotnav.setup.config import Setup, setup_from_toml
from spotnav.setup.examples import EXAMPLE_SETUP

__all__ = ["COMPILE_CPU_S", "compile_seconds", "kernel_cache", "kernels_compiled", "warm_kernels"]

COMPILE_CPU_S = 175.0
"""About how long compiling every kernel takes on one core, s. In two processes the first phase's two tasks take
most of it side by side: 115 s on 2 idle cores (194 s of CPU; ``make test``'s first step, issue 61)."""


def compile_seconds(workers: int) -> float:
    """About how long :func:`warm_kernels` takes in ``workers`` processes, s (a third of it does not divide)."""
    return COMPILE_CPU_S * (0.3 + 0.7 / workers)


_SIZE_PX = 256  # the synthetic frames' size: a kernel's compiled code does not depend on it
_MARK = "spotnav-kernels-compiled.txt"


def _setup(beams: int = 1) -> Setup:
    """The example setup at :data:`_SIZE_PX`, with ``beams`` beams."""
    text = EXAMPLE_SETUP.replace("_px = 5000", f"_px = {_SIZE_PX}")
    setup = setup_from_toml(text)
    return replace(setup, instrument=replace(setup.instrument, beam_count=beams))


def _fit() -> None:
    """The cone fit with both solvers, its checks and covariance, on edges projected from a pose (no frame)."""
    from spotnav.optics.camera import project_points  # each task imports what it runs
    from spotnav.optics.light import edge_angle
    from spotnav.pose.checks import judge_fit
    from spotnav.pose.conefit.solvers import fit_cones
    from spotnav.pose.pipeline import pose_problem, refit_free_axis
    from spotnav.setup.geometry import beam_axes, cone_sphere_curve

    for beams in (1, 3):
        setup = _setup(beams)
        eye, insertion = setup.eye, setup.instrument.insertion_in_eye
        tip = eye.center_in_eye - np.array([0.0, 0.0, eye.radius_mm - 3.0])
        axis = (tip - insertion) / np.linalg.norm(tip - insertion)
        angle = edge_angle(setup)
        beam_directions = beam_axes(axis, beams, setup.instrument.beam_tilt)
        curves = [cone_sphere_curve(tip, beam, angle, eye.center_in_eye, eye.radius_mm, 64) for beam in beam_directions]
        edges = [project_points(setup.camera, curve) for curve in curves]
        problem = pose_problem(setup, edges, list(range(beams)), tip + 0.01, axis, 0.0)
        for solver in ("gauss-newton", "levenberg-marquardt"):
            fit = fit_cones(problem, solver=solver)
            judge_fit(fit, setup, spots=beams)
        refit_free_axis(setup, fit)


def _frame(beams: int) -> tuple[Setup, np.ndarray]:
    """A rendered frame of the example setup with ``beams`` beams, its tip at (1, 1, 5) mm."""
    from spotnav.optics.render import Renderer
    from spotnav.setup.geometry import InstrumentPose

    setup = _setup(beams)
    pose = InstrumentPose.through_insertion(np.array([1.0, 1.0, 5.0]), setup.instrument.insertion_in_eye)
    return setup, Renderer(setup).render(pose, seed=0)


def _read() -> None:
    """Rendering, and reading a frame by the precise method (its fit cached by then)."""
    from spotnav.pose.localize import localize_detailed

    setup, image = _frame(1)
    localize_detailed(image, setup, "precise")


def _thesis() -> None:
    """The thesis's method (its ellipses and apex candidates) on a frame rendered by then, and the search for spots
    that large frames make (a frame shrunk by 4 or more, one row of each cell read)."""
    from spotnav.image.spots import detect_spots_otsu
    from spotnav.pose.localize import localize_detailed

    setup, image = _frame(1)
    localize_detailed(image, setup, "thesis")
    detect_spots_otsu(image, blur_px=3, decimate=4, refine=(1, 3))


def _localize() -> None:
    """Every method on one and three beams (``localize``, ``show``)."""
    from spotnav.pose.localize import METHODS, localize_detailed

    for beams in (1, 3):
        setup, image = _frame(beams)
        for method in METHODS:
            localize_detailed(image, setup, method)


def _track() -> None:
    """Tracking's kernels (its own warm-up) and the whole-frame method's start."""
    from spotnav.app.track import prepare_kernels

    prepare_kernels(_setup())


def _calibrate() -> None:
    """``calibrate``'s fits (with the thesis method's height correction) on frames along the square path."""
    from spotnav.app.calibrate import calibrate, calibrate_height_correction
    from spotnav.app.paths import path_poses
    from spotnav.optics.render import Renderer
    from spotnav.pose.known_frame import KnownFrame

    setup = _setup()
    renderer = Renderer(setup)
    frames = [
        KnownFrame(f"{n}.png", renderer.render(pose, seed=n), pose.tip_in_eye, pose.axis)
        for n, pose in enumerate(path_poses("square", 8, setup.instrument.insertion_in_eye))
    ]
    calibrate(frames, setup, fit=["edge-angle"])
    calibrate_height_correction(frames, setup)


def _studies() -> None:
    """What ``analyze approximation`` (Table 4.1) adds."""
    from spotnav.setup.geometry import approximation_deviation

    approximation_deviation(np.radians(9.0))


# Two phases: the fit and the frame's reading share the fewest kernels, so two cores compile them side by side;
# the others need both, and compile only what is their own once those are cached (run beside the first two, they
# compiled the same kernels again: 160 s of CPU instead of 121).
_TASKS: tuple[Callable[[], None], ...] = (_fit, _read, _thesis, _localize, _calibrate, _track, _studies)
_PHASES = (range(2), range(2, len(_TASKS)))


def _run(index: int) -> tuple[str, float, float]:
    """Run task ``index`` (in a worker process): its name, its wall time and its CPU time, s."""
    start, cpu = time.perf_counter(), time.process_time()
    _TASKS[index]()
    return _TASKS[index].__name__.strip("_"), time.perf_counter() - start, time.process_time() - cpu


def _fingerprint() -> str:
    """What a compiled cache is valid for: the package's sources, Numba, Python and the machine."""
    package = os.path.dirname(os.path.abspath(spotnav.__file__))
    sources = spotnav._sources_fingerprint(package, spotnav._sources(package))
    build = (numba.__version__, np.__version__, sys.version, platform.machine())
    return hashlib.sha256(repr((sources, build)).encode()).hexdigest()


def kernel_cache() -> Path | None:
    """The folder where Numba caches the package's kernels (``NUMBA_CACHE_DIR``'s or beside the sources), or None."""
    from numba.core.caching import CacheImpl  # Numba's own choice of folder

    source = spotnav.__file__
    locators: list[Any] = list(CacheImpl._locator_classes)
    for locator in locators:
        found = locator.from_function(kernel_cache, source)
        if found is not None:
            return Path(found.get_cache_path())
    return None


def kernels_compiled() -> bool:
    """Whether :func:`warm_kernels` compiled every kernel into the cache for the sources as they are."""
    cache = kernel_cache()
    if cache is None:
        return True  # nowhere to cache: nothing to warm once
    try:
        return (cache / _MARK).read_text() == _fingerprint()
    except OSError:
        return False


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    """Start the workers with SIGINT ignored: a Ctrl-C goes to the command, which ends them."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def warm_kernels(workers: int | None = None, report: Callable[[str], None] | None = None) -> dict[str, float]:
    """Compile (or load) every command's kernels, in ``workers`` processes, and mark Numba's cache done.

    Parameters
    ----------
    workers : int, optional
        Processes (default: one per core); 1 runs the tasks in this process.
    report : callable, optional
        Takes the one line that says what is happening and how long it takes.

    Returns
    -------
    dict
        The wall time it took (``"total"``), and each task's CPU time, s.
    """
    workers = max(1, min(workers or _cores(), max(len(phase) for phase in _PHASES)))
    if report is not None:
        cores = f"{workers} idle cores" if workers > 1 else "1 idle core"
        about = f"about {compile_seconds(workers):.0f} s on {cores}, longer on a busy machine"
        report(f"spotnav: compiling spotnav's numerical kernels once, {about} ...")
    start = time.perf_counter()
    if workers == 1:
        done = [_run(index) for index in range(len(_TASKS))]
    else:
        with _sigint_ignored():
            pool = multiprocessing.get_context("spawn").Pool(workers)
        try:
            done = [task for phase in _PHASES for task in pool.map(_run, phase, chunksize=1)]
            pool.close()
        finally:
            pool.terminate()
            pool.join()
    cache = kernel_cache()
    if cache is not None:
        (cache / _MARK).write_text(_fingerprint())
    return {"total": time.perf_counter() - start} | {name: cpu_s for name, _, cpu_s in done}


if __name__ == "__main__":  # python -m spotnav.app.kernels [WORKERS]: warm the cache unless it is
    from spotnav.app.start import terminate_as_interrupt

    if kernels_compiled():
        print(f"spotnav's kernels are compiled, in {kernel_cache()}")
    else:
        try:
            with terminate_as_interrupt():  # the workers end with it
                took = warm_kernels(int(sys.argv[1]) if len(sys.argv) > 1 else None, report=print)
        except KeyboardInterrupt:
            print("interrupted: nothing marked compiled")
            raise SystemExit(130) from None
        tasks = ", ".join(f"{name} {cpu_s:.0f}" for name, cpu_s in took.items() if name != "total")
        print(f"compiled in {took['total']:.0f} s (CPU s per task: {tasks})")
