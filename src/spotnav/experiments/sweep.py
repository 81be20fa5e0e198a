"""Design sweeps: render and localize thousands of frames over a grid or a sample of setups, on Dask.

A sweep file (TOML, :data:`EXAMPLE_SWEEP`; read by
:func:`spotnav.experiments.sweep_file.sweep_from_toml`) names the base
setup, the parameters to vary, the paths, frames per path, the methods and
a seed. The frames are cut into chunks; each chunk is one task that renders and
localizes its frames where it runs (no image leaves the worker) and returns
one row per frame and method. Each finished chunk is written at once as a
Parquet file under ``DIR/chunks``, so an interrupted sweep resumes without
redoing them; at the end the chunks are joined, in plan order, into
``DIR/frames.parquet``. Every frame's noise seed derives from the sweep's
seed and the frame's place in the plan, so the results (all but the timing
columns) do not depend on the number of workers, nor on which worker ran a
chunk.
"""

from __future__ import annotations

import itertools
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from spotnav.app.paths import path_poses
from spotnav.app.progress import progress
from spotnav.experiments.cluster import Workers, check_cluster_options, seed_of, task_runner
from spotnav.experiments.frame import run_timed_frame
from spotnav.experiments.scenes import with_true_edge
from spotnav.experiments.sweep_file import (
    SWEEP_PARAMETERS,
    Sweep,
    SweepError,
    apply_parameters,
    design_points,
    sweep_from_toml,
)
from spotnav.optics.render import Renderer
from spotnav.setup.config import Setup
from spotnav.setup.geometry import angles_between
from spotnav.setup.uncertainty import Uncertainty

__all__ = [
    "EXAMPLE_SWEEP",
    "TIMING_COLUMNS",
    "Chunk",
    "SweepRun",
    "parameter_values",
    "plan_chunks",
    "read_sweep_table",
    "run_chunk",
    "run_sweep",
]

TIMING_COLUMNS = ("render_ms", "localize_ms")
_CHUNKS, _TABLE, _FILE = "chunks", "frames.parquet", "sweep.toml"


@dataclass(frozen=True)
class Chunk:
    """One task: frames ``[start, stop)`` of path ``path`` at design point ``point``."""

    index: int
    point: int
    path: str
    start: int
    stop: int

    @property
    def name(self) -> str:
        """The chunk's file name under ``DIR/chunks``."""
        return f"chunk-{self.index:06d}.parquet"


def parameter_values(setup: Setup) -> dict[str, float]:
    """Every sweep parameter's value in ``setup`` (the true eye radius is the assumed one unless set)."""
    values = {}
    for name in SWEEP_PARAMETERS:
        if name == "size_px":
            values[name] = float(setup.camera.width_px)
        elif name == "world.eye_radius_mm":
            values[name] = float(setup.world.eye_radius_mm or setup.eye.radius_mm)
        else:
            section, key = name.split(".")
            values[name] = float(getattr(getattr(setup, section), key))
    return values


def plan_chunks(sweep: Sweep) -> list[Chunk]:
    """Every design point's paths cut into chunks of ``sweep.chunk_frames`` frames, in plan order."""
    chunks: list[Chunk] = []
    for point, path in itertools.product(range(len(design_points(sweep))), sweep.paths):
        for start in range(0, sweep.frames, sweep.chunk_frames):
            stop = min(start + sweep.chunk_frames, sweep.frames)
            chunks.append(Chunk(len(chunks), point, path, start, stop))
    return chunks


def _frame_seed(sweep: Sweep, chunk: Chunk, frame: int) -> int:
    """The frame's noise seed: from the sweep's seed and the frame's place in the plan only."""
    return seed_of(sweep.seed, chunk.point, sweep.paths.index(chunk.path), frame)


def _pose_columns(prefix: str, tip: np.ndarray, axis: np.ndarray) -> dict[str, float]:
    """A tip and axis as the contract's columns ``x_mm .. dir_z``, each name led by ``prefix``."""
    names = ("x_mm", "y_mm", "z_mm", "dir_x", "dir_y", "dir_z")
    return {prefix + name: float(value) for name, value in zip(names, [*tip, *axis], strict=True)}


def run_chunk(sweep: Sweep, chunk: Chunk) -> list[dict[str, Any]]:
    """Render and localize one chunk's frames with every method: one row per frame and method.

    The precise methods know the simulated geometry exactly and assume the
    edge that the simulated light makes (as if calibrated,
    :func:`spotnav.experiments.scenes.with_true_edge`) unless the base setup
    names an edge angle.
    """
    point = design_points(sweep)[chunk.point]
    world = apply_parameters(sweep.base, point)
    if world.instrument.edge_half_angle_deg is None:
        assumed = with_true_edge(world)
    else:
        assumed = replace(world, uncertainty=Uncertainty.exact())
    renderer = Renderer(world)
    poses = path_poses(chunk.path, sweep.frames, world.instrument.insertion_in_eye, resample=False)
    parameters = parameter_values(world)
    localizers = [(assumed if method.startswith("precise") else world, method) for method in sweep.methods]
    rows = []
    for frame in range(chunk.start, chunk.stop):
        truth = poses[frame]
        timed = run_timed_frame(renderer, truth, _frame_seed(sweep, chunk, frame), localizers)
        for method, estimate, localize_ms in zip(sweep.methods, timed.estimates, timed.localize_ms, strict=True):
            tip = estimate.tip_in_eye if estimate.tip_in_eye is not None else np.full(3, np.nan)
            axis = estimate.axis if estimate.axis is not None else np.full(3, np.nan)
            rows.append(
                {"chunk": chunk.index, "point": chunk.point, **parameters, "path": chunk.path, "frame": frame}
                | {"method": method, "status": estimate.status, "detail": estimate.detail}
                | _pose_columns("", truth.tip_in_eye, truth.axis)
                | _pose_columns("est_", tip, axis)
                | {
                    "error_mm": float(np.linalg.norm(tip - truth.tip_in_eye)),
                    "axis_error_deg": float(np.degrees(angles_between(axis, truth.axis))) if estimate.ok else math.nan,
                    "sigma_mm": float(estimate.sigma_mm),
                    "render_ms": timed.render_ms,
                    "localize_ms": localize_ms,
                }
            )
    return rows


def _write_chunk(directory: Path, chunk: Chunk, rows: list[dict[str, Any]]) -> None:
    """Write one chunk's rows atomically (a partly written file never looks finished)."""
    partial = directory / f".{chunk.name}.partial"
    pq.write_table(pa.Table.from_pylist(rows), partial)
    os.replace(partial, directory / chunk.name)


def _with_detail(table: pa.Table) -> pa.Table:
    """Rows written before the ``detail`` column (by an older spotnav) with it beside ``status``, null: not kept."""
    if "detail" in table.column_names:
        return table
    return table.add_column(table.column_names.index("status") + 1, "detail", pa.nulls(table.num_rows, pa.string()))


def _read_chunks(files: list[Path]) -> tuple[pa.Table, int]:
    """Chunk files joined in order, and how many of them had no ``detail`` column (:func:`_with_detail`)."""
    tables = [pq.read_table(f) for f in files]
    older = sum("detail" not in t.column_names for t in tables)
    return pa.concat_tables([_with_detail(t) for t in tables]), older


def read_sweep_table(directory: Path | str) -> pa.Table:
    """A sweep's rows: ``frames.parquet``, or the chunks written so far if the sweep did not finish.

    Rows from before the ``detail`` column have it null.

    Raises
    ------
    SweepError
        If ``directory`` holds no sweep results.
    """
    directory = Path(directory)
    if (directory / _TABLE).is_file():
        return _with_detail(pq.read_table(directory / _TABLE))
    files = sorted((directory / _CHUNKS).glob("chunk-*.parquet"))
    if not files:
        raise SweepError(f"{directory} holds no sweep results ({_TABLE} or {_CHUNKS}/)")
    return _read_chunks(files)[0]


@dataclass(frozen=True)
class SweepRun:
    """What :func:`run_sweep` did.

    Attributes
    ----------
    frames : int
        Rendered frames in the whole sweep (each localized by every method).
    frames_run : int
        Of them, those rendered in this run.
    chunks_run, chunks_resumed : int
        Chunks computed in this run, and finished chunks found from an earlier run.
    wall_s : float
        Wall time of this run, seconds.
    workers, threads : int
        Dask workers (0 in this process) and their threads in all.
    table : Path
    """

    frames: int
    frames_run: int
    chunks_run: int
    chunks_resumed: int
    wall_s: float
    workers: int
    threads: int
    table: Path

    def summary(self) -> str:
        """What ``spotnav sweep`` prints of the run."""
        where = Workers(self.workers, self.threads).where()
        resumed = f" ({self.chunks_resumed} chunks done before)" if self.chunks_resumed else ""
        rate = self.frames_run / self.wall_s if self.wall_s > 0 else 0.0
        return (
            f"wrote {self.table}: {self.frames} frames{resumed}; {self.frames_run} frames in {self.wall_s:.1f} s "
            f"{where} ({rate:.1f} frames/s)"
        )


def _prepare(directory: Path, text: str, resume: bool) -> set[str]:
    """Create the output folder, or check a resumed one; return the names of its finished chunks."""
    chunks = directory / _CHUNKS
    if (directory / _FILE).exists():
        if not resume:
            raise SweepError(f"{directory} already holds a sweep: pass --resume to finish it, or choose another --out")
        if (directory / _FILE).read_text() != text:
            raise SweepError(f"{directory} holds a different sweep ({_FILE} differs): cannot resume it")
    chunks.mkdir(parents=True, exist_ok=True)
    (directory / _FILE).write_text(text)
    return {f.name for f in chunks.glob("chunk-*.parquet")}


def run_sweep(
    text: str,
    directory: Path | str,
    *,
    base_dir: Path | str = ".",
    scheduler: str | None = None,
    workers: int | None = None,
    resume: bool = False,
    on_chunk: Callable[[Chunk], None] | None = None,
    dashboard: str | None = None,
    log: Callable[[str], None] = print,
    scheduler_timeout_s: float | None = None,
) -> SweepRun:
    """Run a sweep file's frames and write ``directory/frames.parquet``.

    Parameters
    ----------
    text : str
        The sweep file's TOML (kept as ``directory/sweep.toml``).
    directory : path
    base_dir : path
        Where the sweep file's relative paths start.
    scheduler : str, optional
        A Dask scheduler's address (``tcp://HOST:PORT``); by default a
        ``distributed.LocalCluster`` of ``workers`` single-threaded processes.
    workers : int, optional
        The local cluster's workers (default: one per core); 0 runs the chunks
        in this process, without Dask.
    resume : bool
        Finish a sweep that ``directory`` already holds, skipping its finished chunks.
    on_chunk : callable, optional
        Called with each chunk once its file is written.
    dashboard : str, optional
        Serve the local cluster's Dask dashboard at this address (``:8787``;
        ``:0`` picks a free port); its link goes to ``log``. With
        ``scheduler``, the scheduler's own dashboard link is logged.
    log : callable
        Receives the dashboard's link, a line for each Dask worker lost mid-run, and one for resumed chunks
        written before the ``detail`` column.
    scheduler_timeout_s : float, optional
        How long the scheduler may take to answer, to have a worker, and to get one back when all have left
        (:func:`spotnav.experiments.cluster.task_runner`'s ``timeout_s``).

    Raises
    ------
    SweepError
        A bad sweep file, or a folder that holds another sweep (or one without ``resume``).
    spotnav.experiments.cluster.ClusterError
        Cluster options that cannot be used, or a cluster that fails (said in one line).
    """
    check_cluster_options(scheduler, workers, dashboard, scheduler_timeout_s)
    sweep = sweep_from_toml(text, base_dir)
    directory = Path(directory)
    finished = _prepare(directory, text, resume)
    chunks = plan_chunks(sweep)
    todo = [c for c in chunks if c.name not in finished]
    start = time.perf_counter()
    bar = progress(total=len(chunks), initial=len(chunks) - len(todo), desc="sweep", unit="chunk")

    def done(chunk: Chunk, rows: list[dict[str, Any]]) -> None:
        _write_chunk(directory / _CHUNKS, chunk, rows)
        bar.update()
        if on_chunk is not None:
            on_chunk(chunk)

    try:
        with task_runner(scheduler, workers, dashboard, log, scheduler_timeout_s) as (run, used):
            run(partial(run_chunk, sweep), todo, done, "sweep")
    finally:
        bar.close()
    table, older = _read_chunks([directory / _CHUNKS / c.name for c in chunks])
    if older:
        log(f"{older} chunks were written by an older spotnav, without the detail column: theirs is left empty (null)")
    pq.write_table(table, directory / _TABLE)
    frames = sum(c.stop - c.start for c in chunks)
    wall_s = time.perf_counter() - start
    frames_run = sum(c.stop - c.start for c in todo)
    resumed = len(chunks) - len(todo)
    return SweepRun(frames, frames_run, len(todo), resumed, wall_s, used.processes, used.threads, directory / _TABLE)


EXAMPLE_SWEEP = """\
# spotnav sweep: which cone angle and how many beams, at two powers, at 512 px.
# 3 x 2 x 2 = 12 design points x 1 path x 20 frames = 240 frames, each localized
# by both methods (about a minute on two cores). Run it with
#   spotnav sweep sweep.toml --out results/sweep
# and summarise it with
#   spotnav sweep-report results/sweep

seed = 0                      # every frame's noise derives from it: results do not depend on the workers
# setup = "scene.toml"        # base setup (default: the thesis's simulation, Table 6.8)

[grid]                        # every combination of these values
size_px = [512]               # camera width and height
instrument.beam_half_angle_deg = [6.0, 9.0, 12.0]
instrument.beam_count = [1, 3]
light.power_w = [0.1, 1.0]

[random]                      # optional: each grid point repeated `samples` times with uniform draws
samples = 1
# world.eye_radius_mm = [12.0, 13.0]   # true radius (rendered); eye.radius_mm is the one assumed

[frames]
paths = ["helix"]             # square, helix, or CSV files of tips x_mm,y_mm,z_mm
count = 20                    # frames per path and design point
methods = ["thesis", "precise"]
chunk = 10                    # frames per Dask task
"""
"""Example sweep file (:func:`~spotnav.experiments.sweep_file.sweep_from_toml` parses it)."""
