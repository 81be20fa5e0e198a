"""How well the setup's geometry is known: its parameters, the ``[uncertainty]`` and ``[calibration]`` sections.

:data:`GEOMETRY_PARAMETERS` names each small change of the geometry; :class:`Uncertainty` states how well each is
known (1 sigma) where nothing was measured, and :class:`CalibrationRecord` carries the covariance ``spotnav
calibrate`` measured. Both are checked as they are built, each error naming the TOML key.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from spotnav.setup.values import SetupError, in_range, integer, number

__all__ = ["GEOMETRY_PARAMETERS", "CalibrationRecord", "Uncertainty"]


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
    "beam_tilt_deg",
)
"""The geometry's parameters, each a small change of the setup's value (``docs/setup.md``).

The edge model's angle (the beam's edge) and light radius; the eye's radius;
the camera's rotation about its own centre, about its own ``x``, ``y``, ``z``
axes; the camera centre's shift in the eye frame; both focal lengths scaled by
a percentage; the principal point; OpenCV's first five distortion
coefficients; the insertion point's shift; the beams' tilt from the
instrument's axis (several beams). ``[uncertainty]`` and
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
    beam_tilt_deg : float
        The beams' tilt from the instrument's axis (``instrument.beam_tilt_deg``,
        several beams; one beam has none), degrees: how well the fibres'
        directions in the tip are known.
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
    beam_tilt_deg: float = 0.5

    def __post_init__(self) -> None:
        for item in fields(self):
            key = f"uncertainty.{item.name}"
            in_range(key, number(key, getattr(self, item.name)), 0.0, 100.0)

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
    aperture_sigma_mm : float
        1 sigma of ``camera.aperture_mm`` (the lens's depth of field), mm, where
        the calibration measured it from known frames; 0: stated, not measured.
        Outside :data:`GEOMETRY_PARAMETERS`: it moves only clipped spots' edges
        (:func:`spotnav.image.clipped.fit_clipped_edges`).
    """

    parameters: tuple[str, ...] = ()
    covariance: tuple[tuple[float, ...], ...] = ()
    fitted: tuple[str, ...] = ()
    rms_deg: float = 0.0
    frames: int = 0
    frame_edge_sigma_deg: float = 0.0
    aperture_sigma_mm: float = 0.0

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
            matrix.append(tuple(number(f"calibration.covariance[{i}][{j}]", v) for j, v in enumerate(row)))
        array = np.array(matrix, dtype=float).reshape(size, size)
        if size and not np.allclose(array, array.T, rtol=1e-6, atol=1e-12):
            raise SetupError("calibration.covariance must be symmetric")
        if size and np.linalg.eigvalsh(array).min() < -1e-9 * max(float(np.abs(array).max()), 1e-30):
            raise SetupError("calibration.covariance must be positive semi-definite")
        object.__setattr__(self, "covariance", tuple(matrix))
        in_range("calibration.rms_deg", number("calibration.rms_deg", self.rms_deg), 0.0)
        key = "calibration.frame_edge_sigma_deg"
        in_range(key, number(key, self.frame_edge_sigma_deg), 0.0, 10.0)
        in_range("calibration.frames", integer("calibration.frames", self.frames), 0)
        key = "calibration.aperture_sigma_mm"
        in_range(key, number(key, self.aperture_sigma_mm), 0.0, 1000.0)
