"""The whole setup: :class:`Setup`, its sections together, and reading it from TOML.

:func:`setup_from_toml` (and :func:`setup_from_dict`, for TOML already parsed) builds each section's dataclass from
its table and the :class:`Setup` from them; every bad value raises :class:`~spotnav.setup.values.SetupError` with a
one-line message that names the TOML key and the allowed range. Missing sections and keys take the thesis's values;
:func:`missing_keys` names the contract's keys that a setup file must give itself.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from spotnav.setup.microscope import CALIBRATED_KEYS, IDEAL_KEYS, Camera
from spotnav.setup.sections import Bump, Eye, Faults, Instrument, Light, Render, World, check_localized_beams
from spotnav.setup.uncertainty import CalibrationRecord, Uncertainty
from spotnav.setup.values import SetupError, hash_once, state_without_hash

__all__ = ["CONTRACT_KEYS", "Setup", "missing_keys", "setup_from_dict", "setup_from_toml", "toml_data"]


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
            if camera.distance_mm <= 2.0 * radius:  # type: ignore[operator]
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

    __hash__ = hash_once
    __getstate__ = state_without_hash

    @property
    def claims_exact_geometry(self) -> bool:
        """Whether the setup claims its geometry exactly: every ``[uncertainty]`` value 0 and no ``[calibration]``.

        Only a simulation rendered from the setup itself knows its geometry so (the studies); a microscope's is
        known to a real one's tolerance until ``spotnav calibrate`` measures it.
        """
        return self.uncertainty == Uncertainty.exact() and not self.calibration.parameters

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


CONTRACT_KEYS: dict[str, tuple[str, ...]] = {
    "eye": ("radius_mm",),
    "camera": ("width_px", "height_px"),
    "instrument": ("insertion_point_mm", "beam_half_angle_deg", "beam_count"),
}
"""The keys a setup file must give (contract, "The setup file"), besides the camera's model (:data:`IDEAL_KEYS` or
:data:`CALIBRATED_KEYS`) and ``instrument.beam_tilt_deg`` with more than one beam: a localizer needs each of them, and
none has a value that a real microscope shares."""


def missing_keys(data: Mapping[str, Any]) -> list[str]:
    """The contract's keys that a setup file's parsed TOML ``data`` does not give, in the contract's order: a whole
    section as ``"[instrument]"``, a key as ``"camera.distance_mm"``.

    The camera's model is the ideal one's :data:`IDEAL_KEYS` unless the section gives one of the calibrated camera's
    :data:`CALIBRATED_KEYS` (then those four); ``instrument.beam_tilt_deg`` is needed when ``beam_count`` is over 1.
    The Python API's :func:`setup_from_dict` and :func:`setup_from_toml` take the thesis's values for every missing
    key; a setup file read by :func:`spotnav.files.setup_files.read_setup` must give these.
    """
    missing: list[str] = []
    for section, keys in CONTRACT_KEYS.items():
        table = data.get(section)
        if not isinstance(table, Mapping):  # absent (a table of another type is an error of its own)
            missing += [f"[{section}]"] if table is None else []
            continue
        needed = list(keys)
        if section == "camera":
            needed += CALIBRATED_KEYS if any(key in table for key in CALIBRATED_KEYS) else IDEAL_KEYS
        count = table.get("beam_count") if section == "instrument" else None
        if isinstance(count, int) and not isinstance(count, bool) and count > 1:
            needed.append("beam_tilt_deg")
        missing += [f"{section}.{key}" for key in needed if key not in table]
    return missing


def _build_section(name: str, cls: type, table: Any) -> Any:
    if not isinstance(table, Mapping):
        raise SetupError(f"[{name}] must be a table, got {table!r}")
    allowed = {f.name for f in fields(cls)}
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise SetupError(f"{name}.{unknown[0]} is not a known key, allowed: {', '.join(sorted(allowed))}")
    values = dict(table)
    if cls is Camera and any(k in values for k in CALIBRATED_KEYS):
        ideal = [k for k in IDEAL_KEYS if k in values]
        if ideal:
            raise SetupError(
                f"camera.{ideal[0]} cannot be given with a calibrated camera (camera.matrix, camera.distortion, "
                "camera.rotation, camera.translation_mm replace it)"
            )
    if cls is World and "bumps" in values:
        values["bumps"] = tuple(_build_bump(i, b) for i, b in enumerate(_as_list("world.bumps", values["bumps"])))
    section = cls(**values)
    if cls is Instrument:
        check_localized_beams(section)  # the contract's 1 or 3: 2 and 4 beams are the Python API's, for simulation
    return section


def _as_list(key: str, value: Any) -> list[Any]:
    if not isinstance(value, list):
        raise SetupError(f"{key} must be a list, got {value!r}")
    return value


def _build_bump(index: int, value: Any) -> Bump:
    if isinstance(value, Mapping):
        bump: Bump = _build_section(f"world.bumps[{index}]", Bump, value)
        return bump
    raise SetupError(f"world.bumps[{index}] must be a table with x_mm, y_mm, radius_mm, height_mm")


def setup_from_dict(data: Mapping[str, Any], *, complete: bool = False) -> Setup:
    """Build a validated :class:`Setup` from parsed TOML.

    Missing sections and keys take the thesis's values (see :data:`EXAMPLE_SETUP`), unless ``complete``.

    Parameters
    ----------
    data : mapping
        The setup's sections, as TOML tables.
    complete : bool
        Require the contract's keys (:func:`missing_keys`), as a setup file gives them: after each section's own
        checks, before those across sections.

    Raises
    ------
    SetupError
        Naming the first offending key (with ``complete``, every missing key).
    """
    unknown = sorted(set(data) - set(_SECTIONS))
    if unknown:
        raise SetupError(f"[{unknown[0]}] is not a known section, allowed: {', '.join(_SECTIONS)}")
    try:
        sections = {name: _build_section(name, cls, data.get(name, {})) for name, cls in _SECTIONS.items()}
    except TypeError as error:  # a required Bump key is missing
        raise SetupError(f"world.bumps: {error}") from None
    missing = missing_keys(data) if complete else []
    if missing:
        raise SetupError(
            f"incomplete: no {', '.join(missing)} (a setup file gives every key of the contract; "
            "spotnav scene --example prints a whole one)"
        )
    return Setup(**sections)


def setup_from_toml(text: str) -> Setup:
    """Parse and validate a TOML setup.

    Raises
    ------
    SetupError
        For TOML syntax errors and for every invalid key.
    """
    return setup_from_dict(toml_data(text))


def toml_data(text: str) -> dict[str, Any]:
    """A setup's TOML, parsed (not checked).

    Raises
    ------
    SetupError
        For TOML syntax errors.
    """
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise SetupError(f"not valid TOML: {error}") from None
