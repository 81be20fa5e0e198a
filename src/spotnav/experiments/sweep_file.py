"""A sweep file: its TOML read and validated into a :class:`Sweep`, and the design points it plans.

A sweep file (TOML, :data:`spotnav.experiments.sweep.EXAMPLE_SWEEP`) names the base setup, the parameters to vary
(:data:`SWEEP_PARAMETERS`: a grid of values, and/or uniform random ranges), the paths, frames per path, the methods
and a seed. :func:`sweep_from_toml` checks it all, every design point included, before any frame is rendered;
:func:`design_points` draws the points from the seed alone, so the plan is the same on every run.
"""

from __future__ import annotations

import itertools
import math
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from spotnav.errors import InputError, SpotnavError
from spotnav.files.poses import read_path_csv
from spotnav.pose.localize import METHODS
from spotnav.setup.config import Setup, setup_from_toml
from spotnav.setup.sections import check_localized_beams

__all__ = [
    "PATHS",
    "SWEEP_PARAMETERS",
    "Sweep",
    "SweepError",
    "apply_parameters",
    "design_points",
    "flatten_table",
    "sweep_from_toml",
]

# The parameters a sweep may vary: ``section.key`` of the setup, and ``size_px`` (the camera's width and height).
SWEEP_PARAMETERS: dict[str, type] = {
    "size_px": int,
    "instrument.beam_half_angle_deg": float,
    "instrument.beam_count": int,
    "instrument.beam_tilt_deg": float,
    "light.power_w": float,
    "light.blend": float,
    "render.full_well_e": float,
    "render.read_noise_e": float,
    "render.exposure_stops": float,
    "eye.radius_mm": float,
    "world.eye_radius_mm": float,
}
PATHS = ("square", "helix")


class SweepError(InputError):
    """A sweep file's value is missing, of the wrong type or out of range, or a sweep cannot run."""


@dataclass(frozen=True)
class Sweep:
    """A validated sweep (see :func:`sweep_from_toml`).

    Attributes
    ----------
    base : Setup
        The setup every design point starts from.
    grid : tuple of (name, values)
        Every combination of these values is a design point.
    random : tuple of (name, (low, high))
        Each grid point is repeated ``samples`` times, with these parameters
        drawn uniformly (integers inclusive of both ends).
    samples : int
        Design points per grid point (with different noise even without random parameters).
    paths : tuple of str
        ``square``, ``helix`` or CSV files of tips (through the insertion point).
    frames : int
        Frames per path and design point.
    methods : tuple of str
    chunk_frames : int
        Frames per task.
    seed : int
    """

    base: Setup
    grid: tuple[tuple[str, tuple[float | int, ...]], ...]
    random: tuple[tuple[str, tuple[float, float]], ...]
    samples: int
    paths: tuple[str, ...]
    frames: int
    methods: tuple[str, ...]
    chunk_frames: int
    seed: int


def _value(key: str, value: Any, kind: type) -> float | int:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise SweepError(f"{key} must hold finite numbers, got {value!r}")
    if kind is int and not float(value).is_integer():
        raise SweepError(f"{key} must hold integers, got {value!r}")
    result: float | int = kind(value)
    return result


def flatten_table(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"light": {"power_w": v}}`` -> ``{"light.power_w": v}`` (TOML's dotted keys are nested tables)."""
    flat: dict[str, Any] = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat |= flatten_table(value, f"{name}.")
        else:
            flat[name] = value
    return flat


def _parameter(section: str, name: str) -> type:
    if name not in SWEEP_PARAMETERS:
        raise SweepError(f"{section}.{name} is not a sweep parameter, allowed: {', '.join(SWEEP_PARAMETERS)}")
    return SWEEP_PARAMETERS[name]


def _integer(key: str, value: Any, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise SweepError(f"{key} must be an integer >= {low}, got {value!r}")
    return value


def _read_grid(table: Any) -> tuple[tuple[str, tuple[float | int, ...]], ...]:
    if not isinstance(table, Mapping):
        raise SweepError("[grid] must be a table of parameter = [values]")
    grid = []
    for name, values in flatten_table(table).items():
        kind = _parameter("grid", name)
        if not isinstance(values, list) or not values:
            raise SweepError(f"grid.{name} must be a non-empty list of values, got {values!r}")
        grid.append((name, tuple(_value(f"grid.{name}", v, kind) for v in values)))
    return tuple(grid)


def _read_random(table: Any, grid_names: Iterable[str]) -> tuple[int, tuple[tuple[str, tuple[float, float]], ...]]:
    if not isinstance(table, Mapping):
        raise SweepError("[random] must be a table with samples = N and parameter = [low, high]")
    table = flatten_table(table)
    samples = _integer("random.samples", table.pop("samples", 1), 1)
    random = []
    for name, bounds in table.items():
        kind = _parameter("random", name)
        if not isinstance(bounds, list) or len(bounds) != 2:
            raise SweepError(f"random.{name} must be [low, high], got {bounds!r}")
        low, high = (_value(f"random.{name}", v, kind) for v in bounds)
        if not low <= high:
            raise SweepError(f"random.{name} must have low <= high, got {bounds!r}")
        if name in grid_names:
            raise SweepError(f"{name} is both in [grid] and in [random]")
        random.append((name, (float(low), float(high))))
    return samples, tuple(random)


def _read_frames(table: Any, base_dir: Path) -> dict[str, Any]:
    """The ``[frames]`` table as :class:`Sweep`'s keywords ``paths``, ``frames``, ``methods``, ``chunk_frames``."""
    if not isinstance(table, Mapping):
        raise SweepError("[frames] must be a table")
    allowed = {"paths", "count", "methods", "chunk"}
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise SweepError(f"frames.{unknown[0]} is not a known key, allowed: {', '.join(sorted(allowed))}")
    paths = table.get("paths", ["helix"])
    if not isinstance(paths, list) or not paths or not all(isinstance(p, str) for p in paths):
        raise SweepError(f"frames.paths must be a non-empty list of square, helix or CSV files, got {paths!r}")
    paths = [p if p in PATHS else str(base_dir / p) for p in paths]
    for path in paths:
        if path not in PATHS:
            try:
                read_path_csv(path)
            except (OSError, SpotnavError) as error:
                raise SweepError(f"frames.paths: {path}: {error}") from None
    methods = table.get("methods", ["thesis", "precise"])
    if not isinstance(methods, list) or not methods or not all(isinstance(m, str) and m in METHODS for m in methods):
        raise SweepError(f"frames.methods must be a non-empty list from {', '.join(METHODS)}, got {methods!r}")
    return {
        "paths": tuple(paths),
        "frames": _integer("frames.count", table.get("count", 20), 1),
        "methods": tuple(dict.fromkeys(methods)),
        "chunk_frames": _integer("frames.chunk", table.get("chunk", 10), 1),
    }


def sweep_from_toml(text: str, base_dir: Path | str = ".") -> Sweep:
    """Parse and validate a sweep file (see :data:`EXAMPLE_SWEEP`).

    Every design point is built and validated here, so a bad combination
    fails before any frame is rendered.

    Parameters
    ----------
    text : str
        The sweep file's TOML.
    base_dir : path
        Where the file's relative paths (``setup``, path CSVs) start.

    Raises
    ------
    SweepError
        Naming the first offending key (a ``SetupError`` for the setup's own keys).
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise SweepError(f"not valid TOML: {error}") from None
    known = {"seed", "setup", "grid", "random", "frames"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise SweepError(f"{unknown[0]} is not a known key, allowed: {', '.join(sorted(known))}")
    base_dir = Path(base_dir)
    base = Setup()
    if "setup" in data:
        if not isinstance(data["setup"], str):
            raise SweepError(f"setup must be the path of a setup file, got {data['setup']!r}")
        setup_path = base_dir / data["setup"]
        try:
            base = setup_from_toml(setup_path.read_text())
        except OSError as error:
            raise SweepError(f"setup: cannot read {setup_path}: {error.strerror}") from None
    grid = _read_grid(data.get("grid", {}))
    samples, random = _read_random(data.get("random", {}), [name for name, _ in grid])
    sweep = Sweep(
        base=base,
        grid=grid,
        random=random,
        samples=samples,
        seed=_integer("seed", data.get("seed", 0), 0),
        **_read_frames(data.get("frames", {}), base_dir),
    )
    for point in design_points(sweep):
        check_localized_beams(apply_parameters(sweep.base, point).instrument, "a sweep's instrument.beam_count")
    return sweep


def design_points(sweep: Sweep) -> list[dict[str, float | int]]:
    """The sweep's design points in plan order: each grid combination ``samples`` times, with its random draws.

    The draws come from ``sweep.seed`` alone, so the plan is the same on every run.
    """
    names = [name for name, _ in sweep.grid]
    rng = np.random.default_rng(sweep.seed)
    points = []
    for values in itertools.product(*(values for _, values in sweep.grid)):
        for _ in range(sweep.samples):
            point: dict[str, float | int] = dict(zip(names, values, strict=True))
            for name, (low, high) in sweep.random:
                if SWEEP_PARAMETERS[name] is int:
                    point[name] = int(rng.integers(int(low), int(high), endpoint=True))
                else:
                    point[name] = float(rng.uniform(low, high))
            points.append(point)
    return points


def apply_parameters(base: Setup, point: Mapping[str, float | int]) -> Setup:
    """``base`` with a design point's parameters set (see :data:`SWEEP_PARAMETERS`).

    Raises
    ------
    SetupError
        If a value is out of the setup's range (naming the key).
    """
    setup = base
    for name, value in point.items():
        if name == "size_px":
            setup = replace(setup, camera=setup.camera.resized(int(value), int(value)))
        else:
            section, key = name.split(".")
            setup = replace(setup, **{section: replace(getattr(setup, section), **{key: value})})
    return setup
