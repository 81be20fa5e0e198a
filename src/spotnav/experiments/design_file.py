"""A design file: its TOML read and validated into a :class:`DesignSearch`, the candidates it draws and the workspace.

A design file (TOML, :data:`spotnav.experiments.design.EXAMPLE_DESIGN`) names the base setup (a setup file and/or
``[base]`` values), the search space (``[space]``: a list of choices for the integer parameters ``beam_count`` and
``size_px``, a ``[low, high]`` range for the others), the number of candidates, the workspace (a box of random tips
or a named path, the axis through the insertion point), the objective (``max`` or ``p95`` of the tip's bound over
the workspace), the constraints and how many of the best designs to verify by rendering. :func:`design_from_toml`
checks it all, every candidate's setup included, before any bound is computed; :func:`candidate_points` draws the
candidates from the seed alone (a scrambled Sobol sequence), so the plan is the same on every run.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import qmc

from spotnav.app.paths import path_tips
from spotnav.errors import InputError
from spotnav.experiments.sweep_file import PATHS, SWEEP_PARAMETERS, apply_parameters, flatten_table
from spotnav.setup.config import Setup, setup_from_toml
from spotnav.setup.sections import BEAM_COUNTS

__all__ = [
    "DESIGN_PARAMETERS",
    "OBJECTIVES",
    "Constraints",
    "DesignError",
    "DesignSearch",
    "Workspace",
    "candidate_points",
    "design_from_toml",
    "reference_points",
]

# The parameters a design search may vary (the sweep's names); the integers are choices, the others ranges.
DESIGN_PARAMETERS = (
    "instrument.beam_count",
    "instrument.beam_half_angle_deg",
    "instrument.beam_tilt_deg",
    "light.power_w",
    "light.blend",
    "size_px",
)
OBJECTIVES = ("max", "p95")
# The thesis's designs (one beam, 9 deg; three beams tilted 15 deg; blend 0.15), at the base's power and size.
_THESIS_DESIGNS = {
    "thesis, 1 beam": {"instrument.beam_count": 1, "instrument.beam_half_angle_deg": 9.0, "light.blend": 0.15},
    "thesis, 3 beams": {
        "instrument.beam_count": 3,
        "instrument.beam_half_angle_deg": 9.0,
        "instrument.beam_tilt_deg": 15.0,
        "light.blend": 0.15,
    },
}


class DesignError(InputError):
    """A design file's value is missing, of the wrong type or out of range."""


@dataclass(frozen=True)
class Workspace:
    """Where the tip must be known: ``poses`` tips in a box (uniform, seeded) or along a named path.

    Attributes
    ----------
    kind : str
        ``box``, ``square`` or ``helix``.
    poses : int
    min_mm, max_mm : tuple of 3 floats
        The box's corners, eye frame, mm (a path's are unused).
    seed : int
        The box's draws.
    """

    kind: str
    poses: int
    min_mm: tuple[float, float, float] = (-2.5, -2.5, 3.0)
    max_mm: tuple[float, float, float] = (2.5, 2.5, 6.0)
    seed: int = 0

    def tips(self) -> np.ndarray:
        """The workspace's tips, shape (poses, 3), mm."""
        if self.kind != "box":
            return path_tips(self.kind, self.poses)
        rng = np.random.default_rng(self.seed)
        return rng.uniform(self.min_mm, self.max_mm, size=(self.poses, 3))


@dataclass(frozen=True)
class Constraints:
    """What a design must meet.

    Attributes
    ----------
    max_power_w : float
        The light of all the beams together, W (``beam_count * light.power_w``); ``inf``: no limit.
    min_spot_gap_deg : float
        Neighbouring beams' axes must be more than twice the half-angle plus this apart, degrees: their spots never
        touch, at any pose.
    on_fundus : bool
        Every workspace pose's spots lie wholly on the retina's bowl and inside the image (else the design fails
        ``off_fundus``).
    """

    max_power_w: float = math.inf
    min_spot_gap_deg: float = 0.0
    on_fundus: bool = True


@dataclass(frozen=True)
class DesignSearch:
    """A validated design search (see :func:`design_from_toml`).

    Attributes
    ----------
    base : Setup
        The setup every candidate starts from; the thesis's designs take its power and camera.
    space : tuple of (name, values)
        Integers (``instrument.beam_count``, ``size_px``): the choices; floats: ``(low, high)``.
    candidates : int
    objective : str
        ``max`` or ``p95`` of the tip's bound over the workspace.
    workspace : Workspace
    constraints : Constraints
    verify_designs : int
        The best feasible designs verified by rendering (the thesis's designs besides).
    verify_poses : int
        Of the workspace's poses, the first this many are rendered and localized.
    seed : int
    """

    base: Setup
    space: tuple[tuple[str, tuple[float | int, ...]], ...]
    candidates: int
    objective: str
    workspace: Workspace
    constraints: Constraints
    verify_designs: int
    verify_poses: int
    seed: int


def _number(key: str, value: Any, low: float = -math.inf, *, integer: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise DesignError(f"{key} must be a finite number, got {value!r}")
    if integer and not float(value).is_integer():
        raise DesignError(f"{key} must hold integers, got {value!r}")
    if value < low:
        raise DesignError(f"{key} must be >= {low:g}, got {value!r}")
    return float(value)


def _count(key: str, value: Any, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise DesignError(f"{key} must be an integer >= {low}, got {value!r}")
    return value


def _table(data: Mapping[str, Any], name: str, allowed: set[str]) -> dict[str, Any]:
    table = data.get(name, {})
    if not isinstance(table, Mapping):
        raise DesignError(f"[{name}] must be a table")
    table = flatten_table(table)
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise DesignError(f"{name}.{unknown[0]} is not a known key, allowed: {', '.join(sorted(allowed))}")
    return table


def _read_space(data: Mapping[str, Any]) -> tuple[tuple[str, tuple[float | int, ...]], ...]:
    space: list[tuple[str, tuple[float | int, ...]]] = []
    for name, values in _table(data, "space", set(DESIGN_PARAMETERS)).items():
        key = f"space.{name}"
        if SWEEP_PARAMETERS[name] is int:
            if not isinstance(values, list) or not values:
                raise DesignError(f"{key} must be a non-empty list of choices, got {values!r}")
            choices = tuple(dict.fromkeys(int(_number(key, v, 1, integer=True)) for v in values))
            if name == "instrument.beam_count" and not set(choices) <= set(BEAM_COUNTS):
                raise DesignError(f"{key} must be chosen from {', '.join(map(str, BEAM_COUNTS))}, got {values!r}")
            space.append((name, choices))
        else:
            if not isinstance(values, list) or len(values) != 2:
                raise DesignError(f"{key} must be [low, high], got {values!r}")
            low, high = (_number(key, v) for v in values)
            if not low <= high:
                raise DesignError(f"{key} must have low <= high, got {values!r}")
            if name == "light.blend" and low <= 0:
                raise DesignError(f"{key} must be > 0 (the bound needs a soft edge), got {values!r}")
            space.append((name, (low, high)))
    return tuple(space)


def _read_workspace(data: Mapping[str, Any], seed: int, base: Setup) -> Workspace:
    table = _table(data, "workspace", {"kind", "poses", "min_mm", "max_mm"})
    kind = table.get("kind", "box")
    if kind not in ("box", *PATHS):
        raise DesignError(f"workspace.kind must be box, square or helix, got {kind!r}")
    corners: dict[str, tuple[float, float, float]] = {}
    for name, default in (("min_mm", Workspace.min_mm), ("max_mm", Workspace.max_mm)):
        value = table.get(name, list(default))
        if not isinstance(value, list) or len(value) != 3:
            raise DesignError(f"workspace.{name} must be [x, y, z] in mm, got {value!r}")
        x, y, z = (_number(f"workspace.{name}", v) for v in value)
        corners[name] = (x, y, z)
    if not all(lo <= hi for lo, hi in zip(corners["min_mm"], corners["max_mm"], strict=True)):
        raise DesignError("workspace.min_mm must be <= workspace.max_mm in x, y and z")
    workspace = Workspace(kind, _count("workspace.poses", table.get("poses", 24), 1), seed=seed, **corners)
    if kind == "box":
        for corner in np.array(np.meshgrid(*zip(corners["min_mm"], corners["max_mm"], strict=True))).reshape(3, -1).T:
            radius = min(base.eye.radius_mm, base.true_radius_mm)  # inside the eye that renders and the one assumed
            inside = np.linalg.norm(corner - [0.0, 0.0, radius]) < radius - 0.5
            if not inside or not 0 < corner[2] < radius:
                raise DesignError(
                    f"workspace: the box's corner {corner.tolist()} mm is not inside the eye's bowl "
                    f"(0.5 mm from the retina of radius {radius:g} mm, below its equator)"
                )
    return workspace


def _read_constraints(data: Mapping[str, Any]) -> Constraints:
    table = _table(data, "constraints", {"max_power_w", "min_spot_gap_deg", "on_fundus"})
    on_fundus = table.get("on_fundus", True)
    if not isinstance(on_fundus, bool):
        raise DesignError(f"constraints.on_fundus must be true or false, got {on_fundus!r}")
    limit = table.get("max_power_w")
    return Constraints(
        max_power_w=math.inf if limit is None else _number("constraints.max_power_w", limit, 0.0),
        min_spot_gap_deg=_number("constraints.min_spot_gap_deg", table.get("min_spot_gap_deg", 0.0), 0.0),
        on_fundus=on_fundus,
    )


def _read_base(data: Mapping[str, Any], base_dir: Path) -> Setup:
    base = Setup()
    if "setup" in data:
        if not isinstance(data["setup"], str):
            raise DesignError(f"setup must be the path of a setup file, got {data['setup']!r}")
        path = base_dir / data["setup"]
        try:
            base = setup_from_toml(path.read_text())
        except OSError as error:
            raise DesignError(f"setup: cannot read {path}: {error.strerror}") from None
    values = _table(data, "base", set(SWEEP_PARAMETERS))
    point = {
        name: int(_number(f"base.{name}", v, integer=True))
        if SWEEP_PARAMETERS[name] is int
        else _number(f"base.{name}", v)
        for name, v in values.items()
    }
    return apply_parameters(base, point)


def design_from_toml(text: str, base_dir: Path | str = ".") -> DesignSearch:
    """Parse and validate a design file (see :data:`~spotnav.experiments.design.EXAMPLE_DESIGN`).

    Every candidate's setup is built here, so a bad range fails before any bound is computed.

    Parameters
    ----------
    text : str
        The design file's TOML.
    base_dir : path
        Where the file's relative ``setup`` path starts.

    Raises
    ------
    DesignError
        Naming the first offending key (a ``SetupError`` for the setup's own keys).
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise DesignError(f"not valid TOML: {error}") from None
    known = {"seed", "setup", "candidates", "objective", "base", "space", "workspace", "constraints", "verify"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise DesignError(f"{unknown[0]} is not a known key, allowed: {', '.join(sorted(known))}")
    seed = _count("seed", data.get("seed", 0), 0)
    objective = data.get("objective", "max")
    if objective not in OBJECTIVES:
        raise DesignError(f"objective must be max or p95, got {objective!r}")
    verify = _table(data, "verify", {"designs", "poses"})
    base = _read_base(data, Path(base_dir))
    search = DesignSearch(
        base=base,
        space=_read_space(data),
        candidates=_count("candidates", data.get("candidates", 32), 1),
        objective=objective,
        workspace=_read_workspace(data, seed, base),
        constraints=_read_constraints(data),
        verify_designs=_count("verify.designs", verify.get("designs", 3), 0),
        verify_poses=_count("verify.poses", verify.get("poses", 20), 1),
        seed=seed,
    )
    if search.verify_poses > search.workspace.poses:
        raise DesignError(
            f"verify.poses must be <= workspace.poses ({search.workspace.poses}), got {search.verify_poses}"
        )
    for point in [*candidate_points(search), *reference_points(search).values()]:
        apply_parameters(search.base, point)
    return search


def candidate_points(search: DesignSearch) -> list[dict[str, float | int]]:
    """The search's candidates in plan order: a scrambled Sobol sequence over the space, from the seed alone.

    Each integer parameter takes the choice that its coordinate falls in; each float its range's point. A
    single beam has no tilt: it keeps the base's.
    """
    if not search.space:
        return [{} for _ in range(search.candidates)]
    sobol = qmc.Sobol(d=len(search.space), scramble=True, seed=search.seed)
    draws = sobol.random_base2(max(math.ceil(math.log2(search.candidates)), 0))[: search.candidates]
    points = []
    for draw in draws:
        point: dict[str, float | int] = {}
        for u, (name, values) in zip(draw, search.space, strict=True):
            if SWEEP_PARAMETERS[name] is int:
                point[name] = int(values[min(int(u * len(values)), len(values) - 1)])
            else:
                point[name] = float(values[0] + u * (values[1] - values[0]))
        if point.get("instrument.beam_count", search.base.instrument.beam_count) == 1:
            point.pop("instrument.beam_tilt_deg", None)
        points.append(point)
    return points


def reference_points(search: DesignSearch) -> dict[str, dict[str, float | int]]:
    """The thesis's designs (one beam, 9 deg; three beams, 9 deg tilted 15 deg; blend 0.15), label -> point.

    They keep the base's power and camera.
    """
    return {label: dict(point) for label, point in _THESIS_DESIGNS.items()}
