"""A design search: the light (beams, half-angle, tilt, power, blend, camera) whose bound over a workspace is smallest.

A design file (TOML, :data:`EXAMPLE_DESIGN`; read by :func:`spotnav.experiments.design_file.design_from_toml`)
names a search space, a workspace, an objective and constraints. Each candidate is one task (on Dask, as
``sweep``'s chunks): its constraints (power, spots that must not touch, spots on the fundus), then the Cramer-Rao
bound of the tip (:func:`spotnav.pose.bound.pose_bound`) at every workspace pose, and the objective, ``max`` or
``p95`` of the bound. The thesis's designs are evaluated beside them. The best feasible designs and the thesis's
are then verified, one task each: rendered at the workspace's first poses and localized by the model fit (the
efficient estimator, which should reach the bound) and the precise method (spotnav's localizer).
:mod:`spotnav.experiments.design_report` writes the tables and plots.

Two and four beams are simulation's only (no localizer knows them): they are verified by the model fit started
from the true tip displaced by 0.01 mm; one and three beams by the model fit started from the precise method's pose.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from spotnav.app.progress import progress
from spotnav.errors import SpotnavError
from spotnav.experiments.cluster import (
    Result,
    Task,
    TaskRunner,
    Workers,
    check_cluster_options,
    seed_of,
    task_runner,
)
from spotnav.experiments.design_file import DesignSearch, candidate_points, design_from_toml, reference_points
from spotnav.experiments.scenes import with_true_edge
from spotnav.experiments.sweep_file import apply_parameters
from spotnav.optics.camera import project_points
from spotnav.optics.render import Renderer
from spotnav.pose.bound import pose_bound
from spotnav.pose.model_fit import fit_model_to_frame
from spotnav.pose.precise import localize_precise
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose, angles_between, beam_axes, cone_sphere_curve
from spotnav.setup.sections import LOCALIZED_BEAM_COUNTS

__all__ = [
    "EXAMPLE_DESIGN",
    "Candidate",
    "DesignResult",
    "DesignRun",
    "Verification",
    "evaluate_candidate",
    "run_design",
    "verify_design",
]

FEASIBLE = "feasible"
_START_OFFSET_MM = 0.01  # 2 and 4 beams: the model fit starts this far from the true tip
_FUNDUS_SAMPLES = 90  # points along each spot's edge checked to lie on the bowl and in the image


@dataclass(frozen=True)
class Candidate:
    """One design to evaluate: its place in the plan, its label and its parameters (the sweep's names)."""

    index: int
    label: str
    point: Mapping[str, float | int]
    reference: bool = False


@dataclass(frozen=True)
class DesignResult:
    """A candidate's evaluation.

    Attributes
    ----------
    candidate : Candidate
    setup : Setup
        Its world.
    status : str
        ``feasible``, or the constraint it broke: ``power``, ``spots_touch``, ``off_fundus``, ``no_bound``.
    detail : str
    bounds_mm : ndarray, shape (poses,)
        The tip's bound (total, :attr:`~spotnav.pose.bound.PoseBound.tip_mm`) at each workspace pose, mm; NaN
        where not computed.
    objective_mm : float
        ``max`` or ``p95`` of ``bounds_mm``; ``inf`` unless every pose has a bound.
    seconds : float
    """

    candidate: Candidate
    setup: Setup
    status: str
    detail: str = ""
    bounds_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    objective_mm: float = math.inf
    seconds: float = 0.0

    @property
    def feasible(self) -> bool:
        """Whether the design meets every constraint."""
        return self.status == FEASIBLE


def _spot_gap_deg(setup: Setup) -> float:
    """The smallest angle between two beams' cones (between their axes less two half-angles), degrees."""
    instrument = setup.instrument
    if instrument.beam_count == 1:
        return math.inf
    axes = beam_axes(np.array([0.0, 0.0, -1.0]), instrument.beam_count, instrument.beam_tilt)
    pairs = [(i, j) for i in range(len(axes)) for j in range(i + 1, len(axes))]
    closest = min(float(angles_between(axes[i], axes[j])) for i, j in pairs)
    return math.degrees(closest - 2.0 * instrument.beam_half_angle)


def _off_fundus(setup: Setup, pose: InstrumentPose) -> str:
    """Why a pose's spots leave the retina's bowl or the image, or ``""``."""
    radius = setup.true_radius_mm
    centre = np.array([0.0, 0.0, radius])
    instrument, camera = setup.instrument, setup.camera
    for beam, axis in enumerate(beam_axes(pose.axis, instrument.beam_count, instrument.beam_tilt)):
        edge = cone_sphere_curve(pose.tip_in_eye, axis, instrument.beam_half_angle, centre, radius, _FUNDUS_SAMPLES)
        if not np.all(np.isfinite(edge)) or np.any(edge[:, 2] > radius):
            return f"beam {beam}'s spot leaves the retina's bowl"
        pixels = project_points(camera, edge)
        if (
            np.any(pixels < 0)
            or np.any(pixels[:, 0] > camera.width_px - 1)
            or np.any(pixels[:, 1] > camera.height_px - 1)
        ):
            return f"beam {beam}'s spot leaves the image"
    return ""


def workspace_poses(search: DesignSearch, setup: Setup) -> list[InstrumentPose]:
    """The workspace's poses, each axis from the insertion point."""
    insertion = setup.instrument.insertion_in_eye
    return [InstrumentPose.through_insertion(tip, insertion) for tip in search.workspace.tips()]


def evaluate_candidate(search: DesignSearch, candidate: Candidate) -> DesignResult:
    """A candidate's constraints, then its bound at every workspace pose and its objective (one task).

    A design that breaks the power or the spots' gap is not bounded further (the thesis's designs are, to be
    compared); one whose spots leave the fundus at a pose is bounded nowhere.
    """
    start = time.perf_counter()
    setup = apply_parameters(search.base, candidate.point)
    limits, beams = search.constraints, setup.instrument.beam_count
    status, detail = FEASIBLE, ""
    if beams * setup.light.power_w > limits.max_power_w:
        status, detail = "power", f"{beams} x {setup.light.power_w:.3g} W > {limits.max_power_w:g} W"
    elif _spot_gap_deg(setup) <= limits.min_spot_gap_deg:
        status, detail = "spots_touch", f"the cones are {_spot_gap_deg(setup):.2f} deg apart"
    if status != FEASIBLE and not candidate.reference:
        return DesignResult(candidate, setup, status, detail, seconds=time.perf_counter() - start)
    poses = workspace_poses(search, setup)
    bounds = np.full(len(poses), np.nan)
    for index, pose in enumerate(poses):
        off = _off_fundus(setup, pose) if limits.on_fundus else ""
        if off:
            status, detail = (status, detail) if status != FEASIBLE else ("off_fundus", f"pose {index}: {off}")
            bounds[:] = np.nan
            break
        bound = pose_bound(setup, pose)
        if not bound.ok:
            status, detail = (status, detail) if status != FEASIBLE else ("no_bound", f"pose {index}: {bound.status}")
            continue
        bounds[index] = bound.tip_mm
    objective = math.inf
    if np.all(np.isfinite(bounds)):
        objective = float(np.max(bounds) if search.objective == "max" else np.percentile(bounds, 95))
    return DesignResult(candidate, setup, status, detail, bounds, objective, time.perf_counter() - start)


@dataclass(frozen=True)
class Verification:
    """A design rendered at the workspace's first poses and localized (one task of :func:`verify_design`).

    Attributes
    ----------
    index : int
        The candidate's.
    bounds_mm, fit_errors_mm, precise_errors_mm : ndarray, shape (poses,)
        Each pose's bound and the tip errors of the model fit and the precise method, mm (NaN where it gave no pose).
    precise_refused : int
        Frames the precise method refused (1 and 3 beams; their model fit is skipped).
    seconds : float
    fit_bias_mm : float
        The length of the model fit's mean tip error, mm: a bias of the fit, or a difference between the renderer
        and the photometric model, that the bound does not include.
    """

    index: int
    bounds_mm: np.ndarray
    fit_errors_mm: np.ndarray
    precise_errors_mm: np.ndarray
    precise_refused: int
    seconds: float
    fit_bias_mm: float = math.nan

    @staticmethod
    def _rms(values: np.ndarray) -> float:
        return float(np.sqrt(np.mean(values**2))) if len(values) else math.nan

    @property
    def bound_rms_mm(self) -> float:
        """The bound's RMS over the poses the model fit answered, mm."""
        return self._rms(self.bounds_mm[np.isfinite(self.fit_errors_mm)])

    @property
    def fit_rms_mm(self) -> float:
        """The model fit's RMS tip error, mm."""
        return self._rms(self.fit_errors_mm[np.isfinite(self.fit_errors_mm)])

    @property
    def precise_rms_mm(self) -> float:
        """The precise method's RMS tip error over the frames it answered, mm (NaN for 2 or 4 beams)."""
        return self._rms(self.precise_errors_mm[np.isfinite(self.precise_errors_mm)])

    @property
    def precise_bound_rms_mm(self) -> float:
        """The bound's RMS over the frames the precise method answered, mm."""
        return self._rms(self.bounds_mm[np.isfinite(self.precise_errors_mm)])


def verify_design(search: DesignSearch, result: DesignResult) -> Verification:
    """Render a design at the workspace's first ``verify.poses`` poses and localize each frame (one task).

    The model fit knows the world (:func:`~spotnav.pose.model_fit.fit_model_to_frame`); for one or three beams it
    starts from the precise method's pose (knowing the true edge, :func:`~spotnav.experiments.scenes.with_true_edge`)
    and a frame the precise method refuses is counted and skipped; for two or four beams it starts from the true
    tip displaced by 0.01 mm.
    """
    start = time.perf_counter()
    world = result.setup
    renderer, localized = Renderer(world), world.instrument.beam_count in LOCALIZED_BEAM_COUNTS
    assumed = with_true_edge(world)
    poses = workspace_poses(search, world)[: search.verify_poses]
    fit_errors, precise_errors = np.full((len(poses), 3), np.nan), np.full(len(poses), np.nan)
    refused = 0
    for index, truth in enumerate(poses):
        image = renderer.render(truth, seed=seed_of(search.seed, result.candidate.index, index))
        if localized:
            estimate = localize_precise(image, assumed)
            if not estimate.ok or estimate.tip_in_eye is None or estimate.axis is None:
                refused += 1
                continue
            precise_errors[index] = np.linalg.norm(estimate.tip_in_eye - truth.tip_in_eye)
            start_pose = InstrumentPose(estimate.tip_in_eye, estimate.axis)
        else:
            offset = np.full(3, _START_OFFSET_MM / math.sqrt(3.0))
            start_pose = InstrumentPose(truth.tip_in_eye + offset, truth.axis)
        fit = fit_model_to_frame(image, world, start_pose)
        if fit.ok and fit.pose is not None:
            fit_errors[index] = fit.pose.tip_in_eye - truth.tip_in_eye
    bounds = result.bounds_mm[: len(poses)]
    answered = np.all(np.isfinite(fit_errors), axis=1)
    bias = float(np.linalg.norm(fit_errors[answered].mean(axis=0))) if answered.any() else math.nan
    seconds = time.perf_counter() - start
    lengths = np.linalg.norm(fit_errors, axis=1)
    return Verification(result.candidate.index, bounds, lengths, precise_errors, refused, seconds, bias)


@dataclass(frozen=True)
class DesignRun:
    """What :func:`run_design` did.

    Attributes
    ----------
    search : DesignSearch
    results : tuple of DesignResult
        Every candidate's, the thesis's designs first, in plan order.
    ranked : tuple of DesignResult
        The feasible ones, best objective first (the thesis's designs among them if feasible).
    verifications : dict of int to Verification
        By candidate index: the best ``verify.designs`` search designs and the thesis's.
    search_s, verify_s, wall_s : float
        Seconds: the bounds' phase, the verification's and the whole run (the cluster's start included).
    workers, threads : int
        Dask workers (0 in this process) and their threads in all.
    directory : Path
    """

    search: DesignSearch
    results: tuple[DesignResult, ...]
    ranked: tuple[DesignResult, ...]
    verifications: dict[int, Verification]
    search_s: float
    verify_s: float
    wall_s: float
    workers: int
    threads: int
    directory: Path

    @property
    def where(self) -> str:
        """Where the tasks ran: ``in this process``, ``on 1 Dask worker (2 threads)``."""
        return Workers(self.workers, self.threads).where()

    @property
    def best(self) -> DesignResult | None:
        """The best feasible design of the search (not the thesis's), if any."""
        return next((r for r in self.ranked if not r.candidate.reference), None)

    @property
    def references(self) -> tuple[DesignResult, ...]:
        """The thesis's designs' results."""
        return tuple(r for r in self.results if r.candidate.reference)

    def summary(self) -> str:
        """A few lines: what ran where, the best design and the thesis's, each bound beside its simulated error."""
        feasible = sum(r.feasible for r in self.results if not r.candidate.reference)
        lines = [
            f"wrote {self.directory / 'report.md'}: {len(self.results) - len(self.references)} candidates, "
            f"{feasible} feasible, in {self.wall_s:.1f} s {self.where} (bounds {self.search_s:.1f} s, "
            f"verification {self.verify_s:.1f} s)"
        ]
        best = self.best
        for result in ([best] if best is not None else []) + list(self.references):
            line = (
                f"{result.candidate.label}: {result.status}, bound {self.search.objective} {result.objective_mm:.3g} mm"
            )
            check = self.verifications.get(result.candidate.index)
            if check is not None:
                precise = (
                    f"precise RMS {check.precise_rms_mm:.3g} mm"
                    if math.isfinite(check.precise_rms_mm)
                    else "no localizer knows its beams"
                )
                line += (
                    f"; bound RMS {check.bound_rms_mm:.3g} mm, model fit RMS {check.fit_rms_mm:.3g} mm "
                    f"({check.fit_rms_mm / check.bound_rms_mm:.2f}x), {precise}"
                )
            lines.append(line)
        return "\n".join(lines)


def plan_candidates(search: DesignSearch) -> list[Candidate]:
    """The thesis's designs, then the search's candidates, numbered in that order."""
    references = [Candidate(i, label, point, True) for i, (label, point) in enumerate(reference_points(search).items())]
    first = len(references)
    found = [Candidate(first + i, f"design {i}", point) for i, point in enumerate(candidate_points(search))]
    return references + found


def _run_phase(
    run: TaskRunner, function: Callable[[Task], Result], tasks: Sequence[Task], name: str
) -> tuple[list[Result], float]:
    """Run one phase's tasks with a progress bar; their results in plan order, and the seconds it took."""
    start = time.perf_counter()
    results: dict[int, Result] = {}
    bar = progress(total=len(tasks), desc=name, unit="design")

    def done(task: Task, result: Result) -> None:
        results[id(task)] = result
        bar.update()

    try:
        run(function, tasks, done, name)
    finally:
        bar.close()
    return [results[id(task)] for task in tasks], time.perf_counter() - start


def run_design(
    text: str,
    directory: Path | str,
    *,
    base_dir: Path | str = ".",
    scheduler: str | None = None,
    workers: int | None = None,
    dashboard: str | None = None,
    log: Callable[[str], None] = print,
    scheduler_timeout_s: float | None = None,
) -> DesignRun:
    """Search a design file's space, verify its best designs and write the report into ``directory``.

    Parameters
    ----------
    text : str
        The design file's TOML (kept as ``directory/design.toml``).
    directory : path
        Gets ``designs.csv``, ``verified.csv``, ``report.md`` and the plots
        (:func:`spotnav.experiments.design_report.write_design_report`).
    base_dir : path
        Where the design file's relative paths start.
    scheduler, workers, dashboard, log
        As :func:`spotnav.experiments.cluster.task_runner` takes them.
    scheduler_timeout_s : float, optional
        :func:`~spotnav.experiments.cluster.task_runner`'s ``timeout_s``.

    Raises
    ------
    SpotnavError
        A bad design file (:class:`~spotnav.experiments.design_file.DesignError`, naming the key) or cluster options.
    """
    from spotnav.experiments.design_report import write_design_report

    check_cluster_options(scheduler, workers, dashboard, scheduler_timeout_s)
    search = design_from_toml(text, base_dir)
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise SpotnavError(f"--out {directory} is a file, not a folder")
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "design.toml").write_text(text, encoding="utf-8")
    start = time.perf_counter()
    candidates = plan_candidates(search)
    with task_runner(scheduler, workers, dashboard, log, scheduler_timeout_s) as (run, used):
        found, search_s = _run_phase(run, partial(evaluate_candidate, search), candidates, "design")
        results = tuple(found)
        ranked = tuple(sorted((r for r in results if r.feasible), key=lambda r: r.objective_mm))
        chosen = [r for r in ranked if not r.candidate.reference][: search.verify_designs]
        chosen += [r for r in results if r.candidate.reference and np.all(np.isfinite(r.bounds_mm))]
        checked, verify_s = _run_phase(run, partial(verify_design, search), chosen, "verify")
    verifications = {v.index: v for v in checked}
    wall_s = time.perf_counter() - start
    design_run = DesignRun(
        search, results, ranked, verifications, search_s, verify_s, wall_s, used.processes, used.threads, directory
    )
    write_design_report(directory, design_run)
    return design_run


EXAMPLE_DESIGN = """\
# spotnav design: which light localizes the tip best over the working volume, at 512 px.
# 24 candidates (1 to 4 beams) x 16 poses of bounds, then the best 3 and the thesis's two
# designs rendered and localized at 12 poses each (under a minute on two cores). Run it with
#   spotnav design design.toml --out results/design

seed = 0                      # the candidates, the box's tips and every frame's noise derive from it
candidates = 24               # designs drawn from [space] (a scrambled Sobol sequence)
objective = "max"             # max or p95 of the tip's bound over the workspace
# setup = "scene.toml"        # base setup (default: the thesis's simulation, Table 6.8)

[base]                        # the base setup's values: the thesis's designs use its power and size
size_px = 512                 # camera width and height
light.power_w = 1.0           # each beam's power, W

[space]                       # integers: a list of choices; others: [low, high]
instrument.beam_count = [1, 2, 3, 4]
instrument.beam_half_angle_deg = [4.0, 12.0]
instrument.beam_tilt_deg = [8.0, 24.0]        # from the instrument's axis (several beams)
light.power_w = [0.25, 1.5]                   # each beam's
light.blend = [0.05, 0.4]                     # > 0: the bound needs a soft edge
size_px = [512]

[workspace]                   # the axis runs from the insertion point to each tip
kind = "box"                  # box (uniform random tips), square or helix
min_mm = [-2.5, -2.5, 3.0]
max_mm = [2.5, 2.5, 6.0]
poses = 16

[constraints]
max_power_w = 3.0             # all the beams' light together, W (the thesis's three beams: 3 x 1 W)
min_spot_gap_deg = 1.0        # neighbouring cones at least this far apart: spots never touch
on_fundus = true              # every pose's spots wholly on the retina and in the image

[verify]                      # render and localize (model fit, precise) the best designs
designs = 3
poses = 12                    # the workspace's first poses
"""
"""Example design file (:func:`~spotnav.experiments.design_file.design_from_toml` parses it)."""
