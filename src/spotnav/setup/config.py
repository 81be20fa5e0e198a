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
from dataclasses import dataclass, field, fields, replace
from functools import cached_property
from typing import Any

import numpy as np

from spotnav.errors import SpotnavError

__all__ = [
    "EXAMPLES",
    "EXAMPLE_SETUP",
    "GEOMETRY_PARAMETERS",
    "THESIS_EXPOSURE_STOPS",
    "Bump",
    "CalibrationRecord",
    "Camera",
    "Eye",
    "Faults",
    "Instrument",
    "Light",
    "Render",
    "Setup",
    "SetupError",
    "Uncertainty",
    "World",
    "setup_from_dict",
    "setup_from_toml",
]


class SetupError(SpotnavError):
    """A setup value is missing, of the wrong type or out of range."""


def _read_only(array: np.ndarray) -> np.ndarray:
    """``array``, marked read-only: a setup's derived arrays are computed once and shared."""
    array.setflags(write=False)
    return array


def _hash_once(self: Any) -> int:
    """A frozen dataclass's hash, of its fields, computed on first use and kept: the per-setup (and per-camera)
    caches ask for it on every frame, and hashing walks every value of the setup anew."""
    kept = self.__dict__.get("_hash")
    if kept is None:
        kept = self.__dict__["_hash"] = hash(tuple(getattr(self, f.name) for f in fields(self)))
    return kept


def _state_without_hash(self: Any) -> dict[str, Any]:
    """A frozen dataclass's pickled state, without the kept hash: a string's hash differs between processes."""
    return {name: value for name, value in self.__dict__.items() if name != "_hash"}


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

    @cached_property
    def center_in_eye(self) -> np.ndarray:
        """Centre of the retina sphere in the eye frame, shape (3,), mm."""
        return _read_only(np.array([0.0, 0.0, self.radius_mm]))


RESPONSES = ("srgb", "linear", "agx")  # besides a gamma number: how pixel values relate to light
IDEAL_ROTATION = ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0))  # eye frame to the ideal camera's frame
DISTORTION_COUNTS = (4, 5, 8, 12, 14)  # OpenCV's distortion vector lengths
_CALIBRATED_KEYS = ("matrix", "distortion", "rotation", "translation_mm")
_IDEAL_KEYS = ("sensor_width_mm", "focal_length_mm", "distance_mm")
_MAX_LENGTH_MM = 1e6  # a camera's lengths and distance: up to a kilometre
# The focal length over the image's width (fx / width_px): a field of view from 176 deg down to 0.006 deg.
_FOCAL_PER_WIDTH = (0.01, 1e4)
_ORTHONORMAL_TOLERANCE = 1e-6


def _matrix3(key: str, value: Any) -> tuple[tuple[float, float, float], ...]:
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise SetupError(f"{key} must be 3 rows of 3 numbers, got {value!r}")
    return tuple(_vector3(f"{key}[{i}]", row) for i, row in enumerate(value))


@dataclass(frozen=True)
class Camera:
    """The microscope camera: the thesis's ideal pinhole, or a calibrated camera (contract).

    The ideal camera is a pinhole at ``(0, 0, distance_mm)`` looking down ``-z``
    with the principal point at the image's centre. A calibrated camera gives
    instead OpenCV's camera matrix, distortion coefficients and pose (the four
    keys ``matrix``, ``distortion``, ``rotation``, ``translation_mm`` come
    together); its ``sensor_width_mm``, ``focal_length_mm`` and ``distance_mm``
    are ``None``. Every method reads the camera through :attr:`matrix_px`,
    :attr:`distortion_coefficients`, :attr:`rotation_to_camera` and
    :attr:`translation_to_camera_mm`, which the ideal camera fills in too.

    Attributes
    ----------
    width_px, height_px : int
        Image size in pixels.
    sensor_width_mm, focal_length_mm, distance_mm : float or None
        The ideal camera: sensor width (square pixels), focal length and the
        pinhole's height above the pole.
    matrix : tuple of 3 rows of 3 floats, or None
        OpenCV's camera matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``, pixels.
    distortion : tuple of 4, 5, 8, 12 or 14 floats, or None
        OpenCV's distortion coefficients ``(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tau_x, tau_y]]]])``.
    rotation : tuple of 3 rows of 3 floats, or None
        ``R``, eye frame to OpenCV's camera frame (``x`` right, ``y`` down, ``z`` forward).
    translation_mm : tuple of 3 floats, or None
        ``t``: ``x_cam = R x_eye + t``, mm.
    response : str, float or None
        How pixel values relate to light (contract, "The frames' encoding"):
        ``"srgb"`` (the sRGB curve), ``"linear"``, ``"agx"`` (an AgX-like tone
        curve, :func:`spotnav.optics.camera.encode_light`), or a number ``g``: values
        proportional to light ``** (1 / g)``, ``g`` in [0.2, 5]. ``None``: not
        stated; frames are read as sRGB (:attr:`pixel_response`).
    """

    width_px: int = 5000
    height_px: int = 5000
    sensor_width_mm: float | None = 36.0
    focal_length_mm: float | None = 300.0
    distance_mm: float | None = 110.0
    matrix: tuple[tuple[float, float, float], ...] | None = None
    distortion: tuple[float, ...] | None = None
    rotation: tuple[tuple[float, float, float], ...] | None = None
    translation_mm: tuple[float, float, float] | None = None
    response: str | float | None = None

    __hash__ = _hash_once
    __getstate__ = _state_without_hash

    def __post_init__(self) -> None:
        for name in ("width_px", "height_px"):
            value = _integer(f"camera.{name}", getattr(self, name))
            _in_range(f"camera.{name}", value, 16, 20000)
        if isinstance(self.response, str):
            if self.response not in RESPONSES:
                raise SetupError(
                    f"camera.response = {self.response!r} is not allowed, "
                    "allowed 'srgb', 'linear', 'agx' or a gamma number"
                )
        elif self.response is not None:
            _in_range("camera.response", _number("camera.response", self.response), 0.2, 5.0)
            object.__setattr__(self, "response", float(self.response))
        given = [name for name in _CALIBRATED_KEYS if getattr(self, name) is not None]
        if given:
            missing = [name for name in _CALIBRATED_KEYS if name not in given]
            if missing:
                raise SetupError(
                    f"camera.{missing[0]} is missing: a calibrated camera gives "
                    f"{', '.join('camera.' + k for k in _CALIBRATED_KEYS)} together"
                )
            for name in _IDEAL_KEYS:  # the calibrated camera replaces the ideal one's keys
                object.__setattr__(self, name, None)
            self._check_calibrated()
        else:
            for name in _IDEAL_KEYS:
                value = _number(f"camera.{name}", getattr(self, name))
                _in_range(f"camera.{name}", value, 0.0, _MAX_LENGTH_MM, low_open=True)
            ratio = self.focal_length_mm / self.sensor_width_mm  # type: ignore[operator]
            _in_range("camera.focal_length_mm / camera.sensor_width_mm", ratio, *_FOCAL_PER_WIDTH)

    def _check_calibrated(self) -> None:
        matrix = _matrix3("camera.matrix", self.matrix)
        (fx, skew, cx), (zero_a, fy, cy), last = matrix
        for name, value in (("camera.matrix[0][0] (fx)", fx), ("camera.matrix[1][1] (fy)", fy)):
            _in_range(name, value, *(bound * self.width_px for bound in _FOCAL_PER_WIDTH))
        if skew != 0.0 or zero_a != 0.0 or last != (0.0, 0.0, 1.0):
            raise SetupError(f"camera.matrix must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {self.matrix!r}")
        _in_range("camera.matrix[0][2] (cx)", cx, -0.5, self.width_px - 0.5)
        _in_range("camera.matrix[1][2] (cy)", cy, -0.5, self.height_px - 0.5)
        distortion = self.distortion
        if not isinstance(distortion, list | tuple) or len(distortion) not in DISTORTION_COUNTS:
            counts = ", ".join(map(str, DISTORTION_COUNTS))
            raise SetupError(
                f"camera.distortion must be a list of {counts} numbers (OpenCV's order), got {distortion!r}"
            )
        distortion = tuple(_number(f"camera.distortion[{i}]", v) for i, v in enumerate(distortion))
        rotation = _matrix3("camera.rotation", self.rotation)
        array = np.array(rotation)
        if not (np.allclose(array @ array.T, np.eye(3), atol=_ORTHONORMAL_TOLERANCE) and np.linalg.det(array) > 0):
            raise SetupError(
                "camera.rotation must be a rotation matrix (orthonormal to 1e-6, determinant +1), "
                f"got {self.rotation!r}"
            )
        translation = _vector3("camera.translation_mm", self.translation_mm)
        for index, value in enumerate(translation):
            _in_range(f"camera.translation_mm[{index}]", value, -_MAX_LENGTH_MM, _MAX_LENGTH_MM)
        for name, value in (
            ("matrix", matrix),
            ("distortion", distortion),
            ("rotation", rotation),
            ("translation_mm", translation),
        ):
            object.__setattr__(self, name, value)

    @classmethod
    def calibrated(
        cls,
        width_px: int,
        height_px: int,
        matrix: np.ndarray,
        distortion: np.ndarray,
        rotation: np.ndarray,
        translation_mm: np.ndarray,
        response: str | float | None = None,
    ) -> Camera:
        """A calibrated camera from arrays (OpenCV's ``K``, ``dist``, ``R``, ``t``) and its response."""
        return cls(
            width_px=width_px,
            height_px=height_px,
            response=response,
            matrix=tuple(tuple(float(v) for v in row) for row in np.asarray(matrix, dtype=float)),
            distortion=tuple(float(v) for v in np.asarray(distortion, dtype=float).ravel()),
            rotation=tuple(tuple(float(v) for v in row) for row in np.asarray(rotation, dtype=float)),
            translation_mm=tuple(float(v) for v in np.asarray(translation_mm, dtype=float).ravel()),
        )

    @property
    def pixel_response(self) -> str | float:
        """The response frames are read with: :attr:`response`, or ``"srgb"`` when it is not stated."""
        return "srgb" if self.response is None else self.response

    @property
    def is_calibrated(self) -> bool:
        """Whether the camera is given in OpenCV's terms (else it is the thesis's ideal pinhole)."""
        return self.matrix is not None

    @cached_property
    def matrix_px(self) -> np.ndarray:
        """OpenCV's camera matrix ``K``, shape (3, 3), pixels."""
        if self.matrix is not None:
            return _read_only(np.array(self.matrix, dtype=float))
        assert self.focal_length_mm is not None and self.sensor_width_mm is not None
        focal = self.focal_length_mm * self.width_px / self.sensor_width_mm
        cx, cy = (self.width_px - 1) / 2.0, (self.height_px - 1) / 2.0
        return _read_only(np.array([[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]]))

    @cached_property
    def distortion_coefficients(self) -> np.ndarray:
        """OpenCV's distortion coefficients padded with zeros to all 14, shape (14,)."""
        coefficients = np.zeros(14)
        if self.distortion is not None:
            coefficients[: len(self.distortion)] = self.distortion
        return _read_only(coefficients)

    @cached_property
    def rotation_to_camera(self) -> np.ndarray:
        """``R``, eye frame to OpenCV's camera frame, shape (3, 3)."""
        return _read_only(np.array(self.rotation if self.rotation is not None else IDEAL_ROTATION, dtype=float))

    @cached_property
    def translation_to_camera_mm(self) -> np.ndarray:
        """``t`` of ``x_cam = R x_eye + t``, shape (3,), mm."""
        if self.translation_mm is not None:
            return _read_only(np.array(self.translation_mm, dtype=float))
        assert self.distance_mm is not None
        return _read_only(np.array([0.0, 0.0, self.distance_mm]))

    @cached_property
    def focal_px(self) -> float:
        """Focal length in pixels: the mean of ``fx`` and ``fy``."""
        matrix = self.matrix_px
        return float(0.5 * (matrix[0, 0] + matrix[1, 1]))

    @cached_property
    def principal_point_px(self) -> tuple[float, float]:
        """Principal point ``(cx, cy)`` in OpenCV pixel coordinates (the image centre for the ideal camera)."""
        matrix = self.matrix_px
        return (float(matrix[0, 2]), float(matrix[1, 2]))

    @cached_property
    def center_in_eye(self) -> np.ndarray:
        """The camera's centre (pinhole) in the eye frame, ``-R^T t``, shape (3,), mm."""
        return _read_only(-self.rotation_to_camera.T @ self.translation_to_camera_mm)

    def as_calibrated(self) -> Camera:
        """The same camera written with the four calibrated keys."""
        return Camera.calibrated(
            self.width_px,
            self.height_px,
            self.matrix_px,
            self.distortion_coefficients[: len(self.distortion) if self.distortion is not None else 5],
            self.rotation_to_camera,
            self.translation_to_camera_mm,
            self.response,
        )

    def resized(self, width_px: int, height_px: int) -> Camera:
        """The camera with another image size and the same field of view (pixels scaled, as a sensor binned)."""
        if not self.is_calibrated:
            return replace(self, width_px=width_px, height_px=height_px)
        scale = np.array([width_px / self.width_px, height_px / self.height_px])
        matrix = self.matrix_px.copy()
        matrix[[0, 1], [0, 1]] *= scale
        matrix[:2, 2] = (matrix[:2, 2] + 0.5) * scale - 0.5  # pixel centres stay at integers
        return Camera.calibrated(
            width_px,
            height_px,
            matrix,
            self.distortion_coefficients,
            self.rotation_to_camera,
            self.translation_to_camera_mm,
            self.response,
        )


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
        if self.edge_band_deg is not None:
            key = "instrument.edge_band_deg"
            _in_range(key, _number(key, self.edge_band_deg), 0.0, 45.0, high_open=True)
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

    @cached_property
    def insertion_in_eye(self) -> np.ndarray:
        """Insertion point in the eye frame, shape (3,), mm."""
        return _read_only(np.array(self.insertion_point_mm, dtype=float))


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
        _in_range("render.exposure_stops", _number("render.exposure_stops", self.exposure_stops), -20.0, 20.0)
        _in_range("render.ambient", _number("render.ambient", self.ambient), 0.0, 1.0)
        _in_range("render.full_well_e", _number("render.full_well_e", self.full_well_e), 0.0, 1e7)
        _in_range("render.read_noise_e", _number("render.read_noise_e", self.read_noise_e), 0.0, 1e5)
        _in_range("render.supersampling", _integer("render.supersampling", self.supersampling), 1, 16)
        if self.texture not in ("retina", "flat"):
            raise SetupError(f"render.texture = {self.texture!r} is not allowed, allowed 'retina' or 'flat'")
        _integer("render.texture_seed", self.texture_seed)
        if _integer("render.bit_depth", self.bit_depth) not in (8, 16):
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
            _in_range(f"faults.{name}", _integer(f"faults.{name}", getattr(self, name)), 0, 100)
        _in_range("faults.vessel_contrast", _number("faults.vessel_contrast", self.vessel_contrast), 0.0, 1.0)
        _in_range("faults.stray_light", _number("faults.stray_light", self.stray_light), 0.0, 100.0)
        _in_range("faults.motion_blur_px", _number("faults.motion_blur_px", self.motion_blur_px), 0.0, 500.0)
        _in_range("faults.dark_patch", _number("faults.dark_patch", self.dark_patch), 0.0, 1.0)
        for name in ("defocus_px", "frame_blur_px"):
            _in_range(f"faults.{name}", _number(f"faults.{name}", getattr(self, name)), 0.0, 100.0)
        _in_range("faults.glow", _number("faults.glow", self.glow), 0.0, 10.0)


GEOMETRY_PARAMETERS: tuple[str, ...] = (
    "edge_half_angle_deg",
    "light_radius_mm",
    "eye_radius_mm",
    "camera_rotation_x_deg",
    "camera_rotation_y_deg",
    "camera_rotation_z_deg",
    "camera_x_mm",
    "camera_y_mm",
    "camera_z_mm",
    "focal_length_percent",
    "principal_point_u_px",
    "principal_point_v_px",
    "distortion_k1",
    "distortion_k2",
    "distortion_p1",
    "distortion_p2",
    "distortion_k3",
    "insertion_x_mm",
    "insertion_y_mm",
    "insertion_z_mm",
)
"""The geometry's parameters, each a small change of the setup's value (``docs/setup.md``).

The edge model's angle (the beam's edge) and light radius; the eye's radius;
the camera's rotation about its own centre, about its own ``x``, ``y``, ``z``
axes; the camera centre's shift in the eye frame; both focal lengths scaled by
a percentage; the principal point; OpenCV's first five distortion
coefficients; the insertion point's shift. ``[uncertainty]`` and
``[calibration]`` state how well each is known.
"""


@dataclass(frozen=True)
class Uncertainty:
    """How well the setup's geometry is known, 1 sigma (setup section ``[uncertainty]``).

    A setup that does not say gets a real operating microscope's: the precise
    methods add the geometry's uncertainty to every pose's ``sigma_mm`` and
    refuse a pose it makes too uncertain (status ``uncalibrated``). A
    simulation rendered from the setup itself knows its geometry exactly
    (:meth:`exact`). ``[calibration]``, written by ``spotnav calibrate``,
    replaces these values for the parameters it lists.

    Attributes
    ----------
    edge_half_angle_deg : float
        The beam's edge angle (so its half-angle), degrees.
    light_radius_mm : float
        The light's emitting radius, mm.
    eye_radius_mm : float
        The retina's radius, mm.
    camera_rotation_deg : float
        The camera's rotation about each of its axes, degrees.
    camera_position_mm : float
        The camera centre, along each eye-frame axis, mm.
    focal_length_percent : float
        The camera's scale (focal length, magnification), per cent.
    principal_point_percent : float
        The principal point, per cent of the image's width.
    distortion_px : float
        The lens's radial distortion (k1), as its displacement at the middle
        of the image's edge, pixels; k2 is given half of it, k3 and the
        tangential terms (p1, p2) a quarter.
    insertion_point_mm : float
        The insertion point, along each axis, mm.
    """

    edge_half_angle_deg: float = 0.3
    light_radius_mm: float = 0.05
    eye_radius_mm: float = 0.25
    camera_rotation_deg: float = 0.5
    camera_position_mm: float = 0.5
    focal_length_percent: float = 1.0
    principal_point_percent: float = 1.0
    distortion_px: float = 5.0
    insertion_point_mm: float = 0.5

    def __post_init__(self) -> None:
        for item in fields(self):
            key = f"uncertainty.{item.name}"
            _in_range(key, _number(key, getattr(self, item.name)), 0.0, 100.0)

    @classmethod
    def exact(cls) -> Uncertainty:
        """A geometry known exactly: every value 0 (a simulation's own setup)."""
        return cls(**{item.name: 0.0 for item in fields(cls)})


@dataclass(frozen=True)
class CalibrationRecord:
    """The covariance of a calibrated geometry (setup section ``[calibration]``, written by ``spotnav calibrate``).

    Attributes
    ----------
    parameters : tuple of str
        Names from :data:`GEOMETRY_PARAMETERS`, each once.
    covariance : tuple of tuples of float
        Their error covariance around the setup's values, in the names' units
        (degrees, mm, per cent, pixels, or none for distortion coefficients).
    fitted : tuple of str
        The parameters the calibration fitted; the others kept the setup's
        value and their ``[uncertainty]``.
    rms_deg : float
        RMS angle of the calibration's edge points from their cones, degrees.
    frames : int
        Frames the calibration used.
    frame_edge_sigma_deg : float
        How far one frame's edge strays from the edge model as a whole (the
        same for all its spots, beyond each spot's own), degrees: measured on
        the calibration frames, each left out of the fit in turn. 0: not measured.
    """

    parameters: tuple[str, ...] = ()
    covariance: tuple[tuple[float, ...], ...] = ()
    fitted: tuple[str, ...] = ()
    rms_deg: float = 0.0
    frames: int = 0
    frame_edge_sigma_deg: float = 0.0

    def __post_init__(self) -> None:
        for key in ("parameters", "fitted"):
            names = getattr(self, key)
            if not isinstance(names, list | tuple) or not all(isinstance(n, str) for n in names):
                raise SetupError(f"calibration.{key} must be a list of names, got {names!r}")
            unknown = [n for n in names if n not in GEOMETRY_PARAMETERS]
            if unknown:
                raise SetupError(
                    f"calibration.{key}: {unknown[0]!r} is not a known parameter, allowed: "
                    f"{', '.join(GEOMETRY_PARAMETERS)}"
                )
            if len(set(names)) != len(names):
                raise SetupError(f"calibration.{key} names a parameter twice")
            object.__setattr__(self, key, tuple(names))
        size = len(self.parameters)
        rows = self.covariance
        if not isinstance(rows, list | tuple) or len(rows) != size:
            raise SetupError(f"calibration.covariance must be {size} rows of {size} numbers (one per parameter)")
        matrix = []
        for i, row in enumerate(rows):
            if not isinstance(row, list | tuple) or len(row) != size:
                raise SetupError(f"calibration.covariance[{i}] must be {size} numbers")
            matrix.append(tuple(_number(f"calibration.covariance[{i}][{j}]", v) for j, v in enumerate(row)))
        array = np.array(matrix, dtype=float).reshape(size, size)
        if size and not np.allclose(array, array.T, rtol=1e-6, atol=1e-12):
            raise SetupError("calibration.covariance must be symmetric")
        if size and np.linalg.eigvalsh(array).min() < -1e-9 * max(float(np.abs(array).max()), 1e-30):
            raise SetupError("calibration.covariance must be positive semi-definite")
        object.__setattr__(self, "covariance", tuple(matrix))
        _in_range("calibration.rms_deg", _number("calibration.rms_deg", self.rms_deg), 0.0)
        key = "calibration.frame_edge_sigma_deg"
        _in_range(key, _number(key, self.frame_edge_sigma_deg), 0.0, 10.0)
        _in_range("calibration.frames", _integer("calibration.frames", self.frames), 0)


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
    uncertainty: Uncertainty = field(default_factory=Uncertainty)
    calibration: CalibrationRecord = field(default_factory=CalibrationRecord)

    def __post_init__(self) -> None:
        radius = self.eye.radius_mm
        for key, sphere in (("eye.radius_mm", radius), ("world.eye_radius_mm", self.true_radius_mm)):
            self._check_camera_outside(key, sphere)
        gap = np.linalg.norm(self.instrument.insertion_in_eye - self.eye.center_in_eye)
        if gap > radius * (1.0 + 1e-9):
            raise SetupError(
                f"instrument.insertion_point_mm is {gap:g} mm from the eye's centre, "
                f"allowed at most eye.radius_mm = {radius:g} (inside the eye)"
            )

    def _check_camera_outside(self, key: str, radius: float) -> None:
        """The camera must see the bowl of the sphere of ``radius`` from outside it, from above."""
        camera = self.camera
        if not camera.is_calibrated:
            assert camera.distance_mm is not None
            if camera.distance_mm <= 2.0 * radius:
                raise SetupError(
                    f"camera.distance_mm = {camera.distance_mm:g} puts the camera inside the eye, "
                    f"allowed > 2 * {key} = {2 * radius:g}"
                )
            return
        centre = camera.center_in_eye
        if centre[2] <= 2.0 * radius:
            raise SetupError(
                f"camera.translation_mm puts the camera's centre at z = {centre[2]:g} mm, inside the eye or "
                f"beside it, allowed above 2 * {key} = {2 * radius:g}"
            )
        if (camera.rotation_to_camera @ -centre)[2] <= 0:
            raise SetupError("camera.rotation turns the camera away from the eye (the pole is behind it)")

    __hash__ = _hash_once
    __getstate__ = _state_without_hash

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
        offset = np.asarray(point_in_eye, float) - self.eye.center_in_eye  # its length as np.linalg.norm's, unchecked
        return float(np.sqrt(offset.dot(offset))) < self.eye.radius_mm - margin_mm


_SECTIONS: dict[str, type] = {
    "eye": Eye,
    "camera": Camera,
    "instrument": Instrument,
    "light": Light,
    "world": World,
    "render": Render,
    "faults": Faults,
    "uncertainty": Uncertainty,
    "calibration": CalibrationRecord,
}


def _build_section(name: str, cls: type, table: Any) -> Any:
    if not isinstance(table, Mapping):
        raise SetupError(f"[{name}] must be a table, got {table!r}")
    allowed = {f.name for f in fields(cls)}
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise SetupError(f"{name}.{unknown[0]} is not a known key, allowed: {', '.join(sorted(allowed))}")
    values = dict(table)
    if cls is Camera and any(k in values for k in _CALIBRATED_KEYS):
        ideal = [k for k in _IDEAL_KEYS if k in values]
        if ideal:
            raise SetupError(
                f"camera.{ideal[0]} cannot be given with a calibrated camera (camera.matrix, camera.distortion, "
                "camera.rotation, camera.translation_mm replace it)"
            )
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
# response = "srgb"           # pixel values against light: "srgb" (assumed), "linear", "agx" or a gamma
# A calibrated camera replaces the three keys above with OpenCV's (spotnav scene --opencv FILE writes them):
# matrix = [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]   # pixels
# distortion = [k1, k2, p1, p2, k3]                          # 4, 5, 8, 12 or 14 values
# rotation = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]  # eye frame to camera frame
# translation_mm = [0.0, 0.0, 110.0]                         # x_cam = rotation x_eye + translation

[instrument]
insertion_point_mm = [0.0, 6.0, 20.0]   # remote centre of motion
beam_half_angle_deg = 9.0     # cone half-angle (beta), in (0, 45)
beam_count = 1                # 1 or 3
beam_tilt_deg = 15.0          # tilt of each beam from the axis when beam_count = 3
height_correction = 1.0       # thesis method only: section 5.5 height factor, 1 = none
# edge_half_angle_deg = 8.656 # precise method's edge model (default: beta with Blender's blend 0.15)
# light_radius_mm = 0.0       # precise method's edge model: the light's emitting radius (0 = a point)
# edge_band_deg = 0.69        # precise method's light model: the soft band about the edge (default 2 (beta - edge))
shaft_diameter_mm = 0.6       # precise method: ignore the edge the shaft hides (0 = no shaft)

[uncertainty]                 # how well the geometry above is known (1 sigma); the precise methods add it to
                              # every pose's sigma_mm and refuse poses it makes too uncertain (uncalibrated).
                              # A simulation rendered from this very file knows it exactly: every value 0.
                              # Without this section spotnav assumes a real microscope's: edge 0.3 deg, light
                              # radius 0.05 mm, eye radius 0.25 mm, camera 0.5 deg and 0.5 mm, focal length 1 %,
                              # principal point 1 % of the width, distortion 5 px, insertion point 0.5 mm.
                              # spotnav calibrate measures it and writes [calibration].
edge_half_angle_deg = 0.0
light_radius_mm = 0.0
eye_radius_mm = 0.0
camera_rotation_deg = 0.0
camera_position_mm = 0.0
focal_length_percent = 0.0
principal_point_percent = 0.0
distortion_px = 0.0
insertion_point_mm = 0.0

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
bit_depth = 8                 # 8 or 16 bits per channel
tone = "camera"               # "camera" (encode by camera.response) or "agx" (a tone curve like Blender's AgX)

[faults]                      # simulator only: disturbances, all off by default
shaft = false                 # draw the shaft (instrument.shaft_diameter_mm) from the tip to the insertion point
glints = 0                    # specular glints in and around the spot
vessels = 0                   # dark vessels drawn across the spot ...
vessel_contrast = 0.8         # ... absorbing this fraction of the light
stray_light = 0.0             # a second bright source beside the spot: peak in full scales (0 = none)
motion_blur_px = 0.0          # linear motion blur of the spot, pixels
dark_patch = 0.0              # a darker patch of fundus under part of the spot's edge: albedo it lacks (0 = none)
defocus_px = 0.0              # Gaussian blur of the light (defocus), sigma in pixels
frame_blur_px = 0.0           # Gaussian blur of the encoded frame (camera or codec), sigma in pixels
glow = 0.0                    # an endo-illuminator's broad uneven glow: peak, fraction of full scale (0 = none)
"""

# The exposure at which the thesis's spots saturate (docs/methods.md, "The thesis's exposure"): its Figure 6.16
# shows the spot at (0, 0, 8) mm brightening up to 0.5 W and no more from 1 W. A spot stops brightening when it
# is white, full scale in every channel: at 1 W the median of its centre's darkest channel (blue) reaches full
# scale at +4.44 stops on spotnav's retina (spotnav.experiments.chapter6.saturating_exposure_stops), and
# the preset rounds that up to the half stop.
THESIS_EXPOSURE_STOPS = 4.5

EXAMPLES = {
    "thesis": EXAMPLE_SETUP,
    "thesis-exposure": EXAMPLE_SETUP.replace(
        "# spotnav setup: the thesis's simulation (Hennerkes 2020, Table 6.8).\n",
        "# spotnav setup: the thesis's simulation (Hennerkes 2020, Table 6.8), exposed as its Figure 6.16 shows:\n"
        "# the spot is saturated (white) from 1 W up. spotnav's default world is not: it keeps the edge's light.\n",
    ).replace(
        "exposure_stops = 0.0          # 0: white surface 5 mm below 1 W, facing it, is full scale\n",
        f"exposure_stops = {THESIS_EXPOSURE_STOPS}          # the thesis's: a spot 8 mm above the retina is white"
        " from 1 W up\n",
    ),
}
"""Named example setups: ``spotnav scene --example NAME``."""
