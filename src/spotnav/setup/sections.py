"""The setup's sections besides the camera and the geometry's uncertainty: eye, instrument, light, world, render
and faults.

Each is a frozen dataclass that is valid once built: a bad value raises :class:`~spotnav.setup.values.SetupError`
whose message names the TOML key and the allowed range. Lengths are in millimetres and angles in degrees, as in the
setup file; the properties without a unit suffix (``beam_half_angle``) are in radians. ``eye`` and ``instrument``
are the contract's (with ``camera``) and all a localizer may use; ``light``, ``world``, ``render`` and ``faults``
describe the simulated world only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from spotnav.setup.values import SetupError, in_range, integer, number, read_only, vector3

__all__ = [
    "BEAM_COUNTS",
    "LOCALIZED_BEAM_COUNTS",
    "Bump",
    "Eye",
    "Faults",
    "Instrument",
    "Light",
    "Render",
    "World",
    "check_localized_beams",
]

BEAM_COUNTS = (1, 2, 3, 4)
"""The beams an :class:`Instrument` may have: the renderer, the bound and the model fit take any of them."""
LOCALIZED_BEAM_COUNTS = (1, 3)
"""The beams of the contract: a setup file's, and those that the localizers (thesis, precise) know."""


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
        in_range("eye.radius_mm", number("eye.radius_mm", self.radius_mm), 0.0, low_open=True)

    @cached_property
    def center_in_eye(self) -> np.ndarray:
        """Centre of the retina sphere in the eye frame, shape (3,), mm."""
        return read_only(np.array([0.0, 0.0, self.radius_mm]))


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
        1 to 4 (:data:`BEAM_COUNTS`). A setup file and the localizers take 1 or 3
        (:data:`LOCALIZED_BEAM_COUNTS`, :func:`check_localized_beams`); 2 and 4 beams are for
        simulation only (rendering, the bound, the model fit: ``spotnav design``).
    beam_tilt_deg : float
        Tilt of each beam axis from the instrument axis when ``beam_count > 1``.
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
    edge_band_deg : float or None
        The precise method's light model: the width in angle, degrees in
        [0, 45), of the soft band over which the beam's light falls from full
        to none, centred on the edge; a spot whose plateau clips is read from
        its flank by it. ``None``: ``2 (beta - edge)`` (0 where the edge lies
        at or beyond beta). ``spotnav calibrate`` fits it from known frames
        whose spots clip.
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
    edge_band_deg: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(
            self,
            "insertion_point_mm",
            vector3("instrument.insertion_point_mm", self.insertion_point_mm),
        )
        key = "instrument.beam_half_angle_deg"
        in_range(key, number(key, self.beam_half_angle_deg), 0.0, 45.0, low_open=True, high_open=True)
        count = integer("instrument.beam_count", self.beam_count)
        if count not in BEAM_COUNTS:
            raise SetupError(f"instrument.beam_count = {count} is not allowed, allowed 1 to 4")
        key = "instrument.beam_tilt_deg"
        in_range(key, number(key, self.beam_tilt_deg), 0.0, 45.0, high_open=True)
        key = "instrument.height_correction"
        in_range(key, number(key, self.height_correction), 0.5, 2.0)
        if self.edge_half_angle_deg is not None:
            key = "instrument.edge_half_angle_deg"
            in_range(key, number(key, self.edge_half_angle_deg), 0.0, 45.0, low_open=True, high_open=True)
        key = "instrument.light_radius_mm"
        in_range(key, number(key, self.light_radius_mm), 0.0, 1.0, high_open=True)
        if self.edge_band_deg is not None:
            key = "instrument.edge_band_deg"
            in_range(key, number(key, self.edge_band_deg), 0.0, 45.0, high_open=True)
        in_range(
            "instrument.shaft_diameter_mm", number("instrument.shaft_diameter_mm", self.shaft_diameter_mm), 0.0, 5.0
        )

    @property
    def beam_half_angle(self) -> float:
        """Beam half-angle in radians."""
        return math.radians(self.beam_half_angle_deg)

    @property
    def beam_tilt(self) -> float:
        """Beam tilt in radians."""
        return math.radians(self.beam_tilt_deg)

    @cached_property
    def insertion_in_eye(self) -> np.ndarray:
        """Insertion point in the eye frame, shape (3,), mm."""
        return read_only(np.array(self.insertion_point_mm, dtype=float))


def check_localized_beams(instrument: Instrument, key: str = "instrument.beam_count") -> None:
    """Refuse an instrument whose beams no localizer knows (2 or 4: simulation only).

    Raises
    ------
    SetupError
        Naming ``key`` and the allowed counts.
    """
    if instrument.beam_count not in LOCALIZED_BEAM_COUNTS:
        raise SetupError(
            f"{key} = {instrument.beam_count} is not allowed here, allowed 1 or 3 "
            "(2 or 4 beams are for simulation only: render, bound, spotnav design)"
        )


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
        in_range("light.power_w", number("light.power_w", self.power_w), 0.0, 1000.0)
        in_range("light.blend", number("light.blend", self.blend), 0.0, 1.0)


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
            number(f"world.bumps.{name}", getattr(self, name))
        key = "world.bumps.radius_mm"
        in_range(key, number(key, self.radius_mm), 0.0, 5.0, low_open=True)
        key = "world.bumps.height_mm"
        in_range(key, number(key, self.height_mm), -1.0, 1.0)


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
            in_range(key, number(key, self.eye_radius_mm), 0.0, low_open=True)
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
    bit_depth : int
        8 or 16 bits per channel.
    tone : str
        How light becomes pixel values: ``"camera"`` (the camera's
        ``response``) or ``"agx"`` (the AgX-like tone curve, whatever the
        camera's ``response`` says: a camera the setup describes wrongly).
    """

    exposure_stops: float = 0.0
    ambient: float = 0.004
    full_well_e: float = 10000.0
    read_noise_e: float = 8.0
    supersampling: int = 4
    texture: str = "retina"
    texture_seed: int = 0
    bit_depth: int = 8
    tone: str = "camera"

    def __post_init__(self) -> None:
        in_range("render.exposure_stops", number("render.exposure_stops", self.exposure_stops), -20.0, 20.0)
        in_range("render.ambient", number("render.ambient", self.ambient), 0.0, 1.0)
        in_range("render.full_well_e", number("render.full_well_e", self.full_well_e), 0.0, 1e7)
        in_range("render.read_noise_e", number("render.read_noise_e", self.read_noise_e), 0.0, 1e5)
        in_range("render.supersampling", integer("render.supersampling", self.supersampling), 1, 16)
        if self.texture not in ("retina", "flat"):
            raise SetupError(f"render.texture = {self.texture!r} is not allowed, allowed 'retina' or 'flat'")
        integer("render.texture_seed", self.texture_seed)
        if integer("render.bit_depth", self.bit_depth) not in (8, 16):
            raise SetupError(f"render.bit_depth = {self.bit_depth} is not allowed, allowed 8 or 16")
        if self.tone not in ("camera", "agx"):
            raise SetupError(f"render.tone = {self.tone!r} is not allowed, allowed 'camera' or 'agx'")


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
    dark_patch : float
        A darker patch of fundus (pigment) under part of the spot's edge: the
        fraction of albedo it lacks at its centre, in [0, 1]; 0 = none.
    defocus_px : float
        Gaussian blur of the light (defocus, before the camera's encoding), sigma in pixels.
    frame_blur_px : float
        Gaussian blur of the encoded frame (a camera's or codec's smoothing), sigma in pixels.
    glow : float
        An endo-illuminator's broad, uneven glow over about a third of the
        frame: its peak, as a fraction of full scale on a white surface; 0 = none.
    """

    shaft: bool = False
    glints: int = 0
    vessels: int = 0
    vessel_contrast: float = 0.8
    stray_light: float = 0.0
    motion_blur_px: float = 0.0
    dark_patch: float = 0.0
    defocus_px: float = 0.0
    frame_blur_px: float = 0.0
    glow: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.shaft, bool):
            raise SetupError(f"faults.shaft must be true or false, got {self.shaft!r}")
        for name in ("glints", "vessels"):
            in_range(f"faults.{name}", integer(f"faults.{name}", getattr(self, name)), 0, 100)
        in_range("faults.vessel_contrast", number("faults.vessel_contrast", self.vessel_contrast), 0.0, 1.0)
        in_range("faults.stray_light", number("faults.stray_light", self.stray_light), 0.0, 100.0)
        in_range("faults.motion_blur_px", number("faults.motion_blur_px", self.motion_blur_px), 0.0, 500.0)
        in_range("faults.dark_patch", number("faults.dark_patch", self.dark_patch), 0.0, 1.0)
        for name in ("defocus_px", "frame_blur_px"):
            in_range(f"faults.{name}", number(f"faults.{name}", getattr(self, name)), 0.0, 100.0)
        in_range("faults.glow", number("faults.glow", self.glow), 0.0, 10.0)
