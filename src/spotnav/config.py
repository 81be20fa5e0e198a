"""The setup: immutable, validated description of the eye, camera, instrument and light.

Every dataclass here is valid once built: a bad value raises :class:`SetupError`
(a :class:`ValueError`) whose message names the TOML key and the allowed range.
Lengths are in millimetres and angles in degrees, as in the setup file; the
properties without a unit suffix (``beam_half_angle``) are in radians.

The sections ``eye``, ``camera`` and ``instrument`` are the contract's and are all
a localizer may use. ``light``, ``world`` and ``render`` describe the simulated
world only.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

__all__ = [
    "EXAMPLE_SETUP",
    "Bump",
    "Camera",
    "Eye",
    "Faults",
    "Instrument",
    "Light",
    "Render",
    "Setup",
    "SetupError",
    "World",
    "setup_from_dict",
    "setup_from_toml",
]


class SetupError(ValueError):
    """A setup value is missing, of the wrong type or out of range."""


def _number(key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SetupError(f"{key} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise SetupError(f"{key} must be finite, got {value!r}")
    return float(value)


def _integer(key: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise SetupError(f"{key} must be an integer, got {value!r}")
    return value


def _in_range(
    key: str,
    value: float,
    low: float | None = None,
    high: float | None = None,
    *,
    low_open: bool = False,
    high_open: bool = False,
) -> None:
    below = low is not None and (value <= low if low_open else value < low)
    above = high is not None and (value >= high if high_open else value > high)
    if below or above:
        left = "(" if low_open else "["
        right = ")" if high_open else "]"
        lo = "-inf" if low is None else f"{low:g}"
        hi = "inf" if high is None else f"{high:g}"
        raise SetupError(f"{key} = {value:g} is out of range, allowed {left}{lo}, {hi}{right}")


def _vector3(key: str, value: Any) -> tuple[float, float, float]:
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise SetupError(f"{key} must be a list of 3 numbers, got {value!r}")
    x, y, z = (_number(f"{key}[{i}]", v) for i, v in enumerate(value))
    return (x, y, z)


@dataclass(frozen=True)
class Eye:
    """The retina model the localizer assumes: a sphere through the pole.

    Attributes
    ----------
    radius_mm : float
        Radius of the retina sphere, centred at ``(0, 0, radius_mm)`` in the eye frame.
    """

    radius_mm: float = 12.5

    def __post_init__(self) -> None:
        _in_range("eye.radius_mm", _number("eye.radius_mm", self.radius_mm), 0.0, low_open=True)

    @property
    def center_in_eye(self) -> np.ndarray:
        """Centre of the retina sphere in the eye frame, shape (3,), mm."""
        return np.array([0.0, 0.0, self.radius_mm])


@dataclass(frozen=True)
class Camera:
    """Ideal pinhole at ``(0, 0, distance_mm)`` looking down ``-z`` (contract).

    Attributes
    ----------
    width_px, height_px : int
        Image size in pixels.
    sensor_width_mm : float
        Physical sensor width; pixels are square.
    focal_length_mm : float
        Lens focal length.
    distance_mm : float
        Height of the pinhole above the pole.
    """

    width_px: int = 5000
    height_px: int = 5000
    sensor_width_mm: float = 36.0
    focal_length_mm: float = 300.0
    distance_mm: float = 110.0

    def __post_init__(self) -> None:
        for name in ("width_px", "height_px"):
            value = _integer(f"camera.{name}", getattr(self, name))
            _in_range(f"camera.{name}", value, 16, 20000)
        for name in ("sensor_width_mm", "focal_length_mm", "distance_mm"):
            value = _number(f"camera.{name}", getattr(self, name))
            _in_range(f"camera.{name}", value, 0.0, low_open=True)

    @property
    def focal_px(self) -> float:
        """Focal length in pixels, ``fx = fy``."""
        return self.focal_length_mm * self.width_px / self.sensor_width_mm

    @property
    def principal_point_px(self) -> tuple[float, float]:
        """Image centre ``(cx, cy)`` in OpenCV pixel coordinates."""
        return ((self.width_px - 1) / 2.0, (self.height_px - 1) / 2.0)

    @property
    def center_in_eye(self) -> np.ndarray:
        """Pinhole position in the eye frame, shape (3,), mm."""
        return np.array([0.0, 0.0, self.distance_mm])


@dataclass(frozen=True)
class Instrument:
    """The instrument and its light cones (contract section ``[instrument]``).

    Attributes
    ----------
    insertion_point_mm : tuple of 3 floats
        Remote centre of motion in the eye frame; the axis runs from it to the tip.
    beam_half_angle_deg : float
        Half-angle of every beam cone, in (0, 45) degrees (the thesis's beta).
    beam_count : int
        1 or 3.
    beam_tilt_deg : float
        Tilt of each beam axis from the instrument axis when ``beam_count = 3``.
    height_correction : float
        The thesis method's height correction factor (section 5.5), in
        [0.5, 2]: it scales each reconstructed cone triangle. 1 = none.
    edge_half_angle_deg : float or None
        The precise method's edge model: the angle from each beam's axis at
        which the detected edge (the level halfway between the spot's plateau
        and the background) sits, in (0, 45) degrees. ``None``: that of a
        Cycles spot of ``beam_half_angle_deg`` with Blender's default blend 0.15.
    light_radius_mm : float
        The precise method's edge model: radius of the light's emitting face
        (a fibre's core), in [0, 1) mm. The edge is the cone of
        ``edge_half_angle_deg`` widened by this much: its apex lies
        ``light_radius_mm / tan(edge)`` behind the tip. 0: a point source.
    shaft_diameter_mm : float
        Diameter of the instrument's shaft, in [0, 5] mm: the precise method
        ignores the edge that the shaft, from the tip toward the insertion
        point, would hide (0: no shaft).
    """

    insertion_point_mm: tuple[float, float, float] = (0.0, 6.0, 20.0)
    beam_half_angle_deg: float = 9.0
    beam_count: int = 1
    beam_tilt_deg: float = 15.0
    height_correction: float = 1.0
    edge_half_angle_deg: float | None = None
    light_radius_mm: float = 0.0
    shaft_diameter_mm: float = 0.6

    def __post_init__(self) -> None:
        object.__setattr__(
            self,
            "insertion_point_mm",
            _vector3("instrument.insertion_point_mm", self.insertion_point_mm),
        )
        key = "instrument.beam_half_angle_deg"
        _in_range(key, _number(key, self.beam_half_angle_deg), 0.0, 45.0, low_open=True, high_open=True)
        count = _integer("instrument.beam_count", self.beam_count)
        if count not in (1, 3):
            raise SetupError(f"instrument.beam_count = {count} is not allowed, allowed 1 or 3")
        key = "instrument.beam_tilt_deg"
        _in_range(key, _number(key, self.beam_tilt_deg), 0.0, 45.0, high_open=True)
        key = "instrument.height_correction"
        _in_range(key, _number(key, self.height_correction), 0.5, 2.0)
        if self.edge_half_angle_deg is not None:
            key = "instrument.edge_half_angle_deg"
            _in_range(key, _number(key, self.edge_half_angle_deg), 0.0, 45.0, low_open=True, high_open=True)
        key = "instrument.light_radius_mm"
        _in_range(key, _number(key, self.light_radius_mm), 0.0, 1.0, high_open=True)
        _in_range(
            "instrument.shaft_diameter_mm", _number("instrument.shaft_diameter_mm", self.shaft_diameter_mm), 0.0, 5.0
        )

    @property
    def beam_half_angle(self) -> float:
        """Beam half-angle in radians."""
        return math.radians(self.beam_half_angle_deg)

    @property
    def beam_tilt(self) -> float:
        """Beam tilt in radians."""
        return math.radians(self.beam_tilt_deg)

    @property
    def insertion_in_eye(self) -> np.ndarray:
        """Insertion point in the eye frame, shape (3,), mm."""
        return np.array(self.insertion_point_mm, dtype=float)


@dataclass(frozen=True)
class Light:
    """The simulated spot light, in Blender's conventions.

    Attributes
    ----------
    power_w : float
        Spot power; radiant intensity ``power_w / (4 pi)`` W/sr on the axis.
    blend : float
        Blender's ``spot_blend`` in [0, 1]: soft edge over the outer part of the cone.
    """

    power_w: float = 1.0
    blend: float = 0.15

    def __post_init__(self) -> None:
        _in_range("light.power_w", _number("light.power_w", self.power_w), 0.0, 1000.0)
        _in_range("light.blend", _number("light.blend", self.blend), 0.0, 1.0)


@dataclass(frozen=True)
class Bump:
    """A Gaussian bump raised from the retina toward the eye's centre (thesis 6.7).

    Attributes
    ----------
    x_mm, y_mm : float
        Centre of the bump, in eye-frame x and y.
    radius_mm : float
        Twice the Gaussian's sigma: the bump is nearly flat beyond it.
    height_mm : float
        Peak displacement toward the centre of the sphere.
    """

    x_mm: float
    y_mm: float
    radius_mm: float = 0.25
    height_mm: float = 0.1

    def __post_init__(self) -> None:
        for name in ("x_mm", "y_mm"):
            _number(f"world.bumps.{name}", getattr(self, name))
        key = "world.bumps.radius_mm"
        _in_range(key, _number(key, self.radius_mm), 0.0, 5.0, low_open=True)
        key = "world.bumps.height_mm"
        _in_range(key, _number(key, self.height_mm), -1.0, 1.0)


@dataclass(frozen=True)
class World:
    """Where the simulated world differs from the localizer's model.

    Attributes
    ----------
    eye_radius_mm : float or None
        True retina radius used for rendering; ``None`` means ``eye.radius_mm``.
    bumps : tuple of Bump
        Deformations of the retina.
    surface : str
        ``"sphere"`` (the retina) or ``"plane"``: the plane ``z = 0`` through the
        pole, for the thesis's ellipse tests (section 6.2).
    """

    eye_radius_mm: float | None = None
    bumps: tuple[Bump, ...] = ()
    surface: str = "sphere"

    def __post_init__(self) -> None:
        if self.eye_radius_mm is not None:
            key = "world.eye_radius_mm"
            _in_range(key, _number(key, self.eye_radius_mm), 0.0, low_open=True)
        object.__setattr__(self, "bumps", tuple(self.bumps))
        if self.surface not in ("sphere", "plane"):
            raise SetupError(f"world.surface = {self.surface!r} is not allowed, allowed 'sphere' or 'plane'")
        if self.surface == "plane" and self.bumps:
            raise SetupError("world.bumps need world.surface = 'sphere'; the plane has no bumps")


@dataclass(frozen=True)
class Render:
    """How the built-in renderer turns light into 8-bit pixels.

    Attributes
    ----------
    exposure_stops : float
        Exposure relative to the default, at which a white Lambertian surface 5 mm
        below a 1 W source, facing it, is exactly full scale.
    ambient : float
        Dim ambient radiance as a fraction of full scale (times the albedo).
    full_well_e : float
        Electrons at full scale (shot noise); 0 disables all noise.
    read_noise_e : float
        Gaussian read noise in electrons.
    supersampling : int
        Sub-samples per pixel side on pixels that the cone's edge crosses.
    texture : str
        ``"retina"`` (procedural fundus) or ``"flat"`` (uniform albedo).
    texture_seed : int
        Seed of the procedural texture.
    """

    exposure_stops: float = 0.0
    ambient: float = 0.004
    full_well_e: float = 10000.0
    read_noise_e: float = 8.0
    supersampling: int = 4
    texture: str = "retina"
    texture_seed: int = 0

    def __post_init__(self) -> None:
        _in_range("render.exposure_stops", _number("render.exposure_stops", self.exposure_stops), -20.0, 20.0)
        _in_range("render.ambient", _number("render.ambient", self.ambient), 0.0, 1.0)
        _in_range("render.full_well_e", _number("render.full_well_e", self.full_well_e), 0.0, 1e7)
        _in_range("render.read_noise_e", _number("render.read_noise_e", self.read_noise_e), 0.0, 1e5)
        _in_range("render.supersampling", _integer("render.supersampling", self.supersampling), 1, 16)
        if self.texture not in ("retina", "flat"):
            raise SetupError(f"render.texture = {self.texture!r} is not allowed, allowed 'retina' or 'flat'")
        _integer("render.texture_seed", self.texture_seed)


@dataclass(frozen=True)
class Faults:
    """Disturbances the built-in renderer adds to every frame (simulator only; all off by default).

    Each frame's random placements derive from its noise seed.

    Attributes
    ----------
    shaft : bool
        Draw the instrument's shaft: an opaque cylinder of
        ``instrument.shaft_diameter_mm`` from the tip to the insertion point,
        which hides the retina (and part of the spot) behind it.
    glints : int
        Specular glints (tiny saturated highlights) on the retina in and around the spot.
    vessels : int
        Dark vessels drawn across the spot.
    vessel_contrast : float
        How much of the light a vessel absorbs, in [0, 1].
    stray_light : float
        Peak of a second bright source (the endo-illuminator's reflection) beside
        the spot, in full scales (above 1 it saturates); 0 = none.
    motion_blur_px : float
        Length of a linear motion blur of the spot, pixels, in a random direction.
    """

    shaft: bool = False
    glints: int = 0
    vessels: int = 0
    vessel_contrast: float = 0.8
    stray_light: float = 0.0
    motion_blur_px: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.shaft, bool):
            raise SetupError(f"faults.shaft must be true or false, got {self.shaft!r}")
        for name in ("glints", "vessels"):
            _in_range(f"faults.{name}", _integer(f"faults.{name}", getattr(self, name)), 0, 100)
        _in_range("faults.vessel_contrast", _number("faults.vessel_contrast", self.vessel_contrast), 0.0, 1.0)
        _in_range("faults.stray_light", _number("faults.stray_light", self.stray_light), 0.0, 100.0)
        _in_range("faults.motion_blur_px", _number("faults.motion_blur_px", self.motion_blur_px), 0.0, 500.0)


@dataclass(frozen=True)
class Setup:
    """A whole setup: the contract's sections plus the simulator's own.

    Cross-section checks: the camera must be outside the eye and the insertion
    point inside it (or on its wall).
    """

    eye: Eye = field(default_factory=Eye)
    camera: Camera = field(default_factory=Camera)
    instrument: Instrument = field(default_factory=Instrument)
    light: Light = field(default_factory=Light)
    world: World = field(default_factory=World)
    render: Render = field(default_factory=Render)
    faults: Faults = field(default_factory=Faults)

    def __post_init__(self) -> None:
        radius = self.eye.radius_mm
        if self.camera.distance_mm <= 2.0 * radius:
            raise SetupError(
                f"camera.distance_mm = {self.camera.distance_mm:g} puts the camera inside the eye, "
                f"allowed > 2 * eye.radius_mm = {2 * radius:g}"
            )
        true_radius = self.true_radius_mm
        if self.camera.distance_mm <= 2.0 * true_radius:
            raise SetupError(
                f"camera.distance_mm = {self.camera.distance_mm:g} puts the camera inside the eye, "
                f"allowed > 2 * world.eye_radius_mm = {2 * true_radius:g}"
            )
        gap = np.linalg.norm(self.instrument.insertion_in_eye - self.eye.center_in_eye)
        if gap > radius * (1.0 + 1e-9):
            raise SetupError(
                f"instrument.insertion_point_mm is {gap:g} mm from the eye's centre, "
                f"allowed at most eye.radius_mm = {radius:g} (inside the eye)"
            )

    @property
    def true_radius_mm(self) -> float:
        """Radius of the simulated retina (``world.eye_radius_mm`` or ``eye.radius_mm``)."""
        return self.world.eye_radius_mm if self.world.eye_radius_mm is not None else self.eye.radius_mm

    def contains_point(self, point_in_eye: np.ndarray, margin_mm: float = 0.0) -> bool:
        """Whether a point lies inside the modelled eye (sphere and below its equator).

        Parameters
        ----------
        point_in_eye : ndarray, shape (3,)
            Point in the eye frame, mm.
        margin_mm : float
            Required clearance from the retina.
        """
        gap = float(np.linalg.norm(np.asarray(point_in_eye, float) - self.eye.center_in_eye))
        return gap < self.eye.radius_mm - margin_mm


_SECTIONS: dict[str, type] = {
    "eye": Eye,
    "camera": Camera,
    "instrument": Instrument,
    "light": Light,
    "world": World,
    "render": Render,
    "faults": Faults,
}


def _build_section(name: str, cls: type, table: Any) -> Any:
    if not isinstance(table, Mapping):
        raise SetupError(f"[{name}] must be a table, got {table!r}")
    allowed = {f.name for f in fields(cls)}
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise SetupError(f"{name}.{unknown[0]} is not a known key, allowed: {', '.join(sorted(allowed))}")
    values = dict(table)
    if cls is World and "bumps" in values:
        values["bumps"] = tuple(_build_bump(i, b) for i, b in enumerate(_as_list("world.bumps", values["bumps"])))
    return cls(**values)


def _as_list(key: str, value: Any) -> list[Any]:
    if not isinstance(value, list):
        raise SetupError(f"{key} must be a list, got {value!r}")
    return value


def _build_bump(index: int, value: Any) -> Bump:
    if isinstance(value, Mapping):
        return _build_section(f"world.bumps[{index}]", Bump, value)
    raise SetupError(f"world.bumps[{index}] must be a table with x_mm, y_mm, radius_mm, height_mm")


def setup_from_dict(data: Mapping[str, Any]) -> Setup:
    """Build a validated :class:`Setup` from parsed TOML.

    Missing sections and keys take the thesis's values (see :data:`EXAMPLE_SETUP`).

    Raises
    ------
    SetupError
        Naming the first offending key.
    """
    unknown = sorted(set(data) - set(_SECTIONS))
    if unknown:
        raise SetupError(f"[{unknown[0]}] is not a known section, allowed: {', '.join(_SECTIONS)}")
    try:
        sections = {name: _build_section(name, cls, data.get(name, {})) for name, cls in _SECTIONS.items()}
    except TypeError as error:  # a required Bump key is missing
        raise SetupError(f"world.bumps: {error}") from None
    return Setup(**sections)


def setup_from_toml(text: str) -> Setup:
    """Parse and validate a TOML setup.

    Raises
    ------
    SetupError
        For TOML syntax errors and for every invalid key.
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise SetupError(f"not valid TOML: {error}") from None
    return setup_from_dict(data)


EXAMPLE_SETUP = """\
# spotnav setup: the thesis's simulation (Hennerkes 2020, Table 6.8).
# Lengths in mm, angles in degrees. The eye frame has its origin at the pole
# (lowest point of the retina), +z up toward the camera.

[eye]
radius_mm = 12.5              # retina sphere, centred at (0, 0, radius_mm)

[camera]                      # pinhole at (0, 0, distance_mm) looking down -z
width_px = 5000
height_px = 5000
sensor_width_mm = 36.0
focal_length_mm = 300.0
distance_mm = 110.0           # height of the pinhole above the pole

[instrument]
insertion_point_mm = [0.0, 6.0, 20.0]   # remote centre of motion
beam_half_angle_deg = 9.0     # cone half-angle (beta), in (0, 45)
beam_count = 1                # 1 or 3
beam_tilt_deg = 15.0          # tilt of each beam from the axis when beam_count = 3
height_correction = 1.0       # thesis method only: section 5.5 height factor, 1 = none
# edge_half_angle_deg = 8.656 # precise method's edge model (default: beta with Blender's blend 0.15)
# light_radius_mm = 0.0       # precise method's edge model: the light's emitting radius (0 = a point)
shaft_diameter_mm = 0.6       # precise method: ignore the edge the shaft hides (0 = no shaft)

[light]                       # simulator only, Blender's conventions
power_w = 1.0                 # radiant intensity power_w / (4 pi) W/sr on the axis
blend = 0.15                  # soft edge over the outer part of the cone, 0 = sharp

[world]                       # simulator only: where the world differs from [eye]
# eye_radius_mm = 13.5        # true retina radius (default: eye.radius_mm)
# bumps = [{ x_mm = 0.0, y_mm = 0.0, radius_mm = 0.25, height_mm = 0.1 }]
surface = "sphere"            # "sphere" (retina) or "plane" (z = 0, thesis section 6.2)

[render]                      # simulator only: the built-in renderer
exposure_stops = 0.0          # 0: white surface 5 mm below 1 W, facing it, is full scale
ambient = 0.004               # dim ambient light, fraction of full scale
full_well_e = 10000.0         # electrons at full scale (shot noise); 0 = no noise
read_noise_e = 8.0            # Gaussian read noise, electrons
supersampling = 4             # sub-samples per pixel side along the cone's edge
texture = "retina"            # "retina" (procedural fundus) or "flat"
texture_seed = 0

[faults]                      # simulator only: disturbances, all off by default
shaft = false                 # draw the shaft (instrument.shaft_diameter_mm) from the tip to the insertion point
glints = 0                    # specular glints in and around the spot
vessels = 0                   # dark vessels drawn across the spot ...
vessel_contrast = 0.8         # ... absorbing this fraction of the light
stray_light = 0.0             # a second bright source beside the spot: peak in full scales (0 = none)
motion_blur_px = 0.0          # linear motion blur of the spot, pixels
"""
