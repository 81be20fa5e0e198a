"""The geometry's parameters: the shared vector's layout, its units, its prior and its mapping to and from a setup.

Shared by all frames of a cone fit, the geometry (:data:`SHARED_SIZE` values,
:data:`spotnav.setup.uncertainty.GEOMETRY_PARAMETERS`, each a change of the setup's value): the edge angle, the light's
radius, the eye's radius, the camera's rotation, centre, focal length, principal point and distortion, the
insertion point and the beams' tilt, grouped as calibrate's flags name them (:data:`PARAMETER_GROUPS`). Per frame
(:data:`FRAME_PARAMETERS`): the tip, the instrument axis (through the insertion point, free as two angles, or known,
:data:`AXIS_MODES`) and the roll of three beams. How well the setup knows its geometry is
:func:`geometry_covariance`.
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np

from spotnav.optics.camera import CHANGE_SIZE, camera_model, camera_of_model, perturbed_model
from spotnav.optics.light import edge_angle
from spotnav.setup.config import Setup
from spotnav.setup.uncertainty import GEOMETRY_PARAMETERS

__all__ = [
    "AXIS_MODES",
    "EDGE_CONTOUR_SIGMA",
    "EDGE_MODEL_SIGMA",
    "FRAME_PARAMETERS",
    "PARAMETER_GROUPS",
    "SHARED_SIZE",
    "geometry_covariance",
    "geometry_to_file_units",
    "geometry_values",
    "group_of",
    "prior_sigmas",
    "setup_with_geometry",
]

# The edge model's own uncertainty (shared by all spots: how the half-light level follows the light) and the shift
# of one spot's whole edge by the texture and vessels under it (each spot its own; some 0.006-0.0095 deg rms over
# the 5000 px paths at 1-2 W).
EDGE_MODEL_SIGMA = float(np.radians(0.003))
EDGE_CONTOUR_SIGMA = float(np.radians(0.007))

SHARED_SIZE = len(GEOMETRY_PARAMETERS)
_EDGE, _LIGHT, _RADIUS, _CAMERA = 0, 1, 2, 3  # where each part of the shared vector starts
_CAMERA_END = _INSERTION = _CAMERA + CHANGE_SIZE
_TILT = _INSERTION + 3
# File units (degrees, per cent) to the engine's (radians, fractions), per shared parameter.
_TO_ENGINE = np.ones(SHARED_SIZE)
_TO_ENGINE[[_EDGE, _CAMERA, _CAMERA + 1, _CAMERA + 2, _TILT]] = np.pi / 180.0
_TO_ENGINE[_CAMERA + 6] = 0.01
# A lens's distortion beyond k1 is smaller: these shares of the stated displacement for k2, k3 and p1, p2.
_K2_SHARE, _K3_SHARE, _TANGENTIAL_SHARE = 0.5, 0.25, 0.25
# The shared parameters by what they describe (the names calibrate's flags use).
PARAMETER_GROUPS: dict[str, tuple[int, ...]] = {
    "edge-angle": (_EDGE,),
    "light-radius": (_LIGHT,),
    "eye-radius": (_RADIUS,),
    "camera-rotation": (_CAMERA, _CAMERA + 1, _CAMERA + 2),
    "camera-position": (_CAMERA + 3, _CAMERA + 4, _CAMERA + 5),
    "focal-length": (_CAMERA + 6,),
    "principal-point": (_CAMERA + 7, _CAMERA + 8),
    "distortion": tuple(range(_CAMERA + 9, _CAMERA_END)),
    "insertion-point": (_INSERTION, _INSERTION + 1, _INSERTION + 2),
    "beam-tilt": (_TILT,),
}


def group_of(index: int) -> str:
    """The :data:`PARAMETER_GROUPS` name of a shared parameter."""
    return next(name for name, ids in PARAMETER_GROUPS.items() if index in ids)


FRAME_PARAMETERS = ("tip_x_mm", "tip_y_mm", "tip_z_mm", "about_y", "about_z", "roll")
_FRAME_SIZE = len(FRAME_PARAMETERS)
AXIS_MODES = {"insertion": 0, "free": 1, "known": 2}


def prior_sigmas(setup: Setup) -> np.ndarray:
    """The ``[uncertainty]`` section as 1-sigma values of the shared parameters, engine units, shape (SHARED_SIZE,).

    A distortion's displacement at the middle of the image's edge (``r``, in
    normalized coordinates) becomes a coefficient: ``px / (f r^3)`` for ``k1``;
    the higher radial terms and the tangential ones, smaller in real lenses,
    get a share of it (:data:`_K2_SHARE`, :data:`_K3_SHARE`,
    :data:`_TANGENTIAL_SHARE`): ``r^5`` for ``k2``, ``r^7`` for ``k3``,
    ``r^2`` for ``p1`` and ``p2``. One beam has no tilt (0).
    """
    uncertainty, camera = setup.uncertainty, setup.camera
    focal = camera.focal_px
    edge = 0.5 * max(camera.width_px, camera.height_px) / focal
    distortion = uncertainty.distortion_px / focal
    principal_px = uncertainty.principal_point_percent / 100.0 * camera.width_px
    values = np.array(
        [
            uncertainty.edge_half_angle_deg,
            uncertainty.light_radius_mm,
            uncertainty.eye_radius_mm,
            *[uncertainty.camera_rotation_deg] * 3,
            *[uncertainty.camera_position_mm] * 3,
            uncertainty.focal_length_percent,
            principal_px,
            principal_px,
            distortion / edge**3,
            _K2_SHARE * distortion / edge**5,
            _TANGENTIAL_SHARE * distortion / edge**2,
            _TANGENTIAL_SHARE * distortion / edge**2,
            _K3_SHARE * distortion / edge**7,
            *[uncertainty.insertion_point_mm] * 3,
            uncertainty.beam_tilt_deg if setup.instrument.beam_count > 1 else 0.0,
        ]
    )
    return values * _TO_ENGINE


def geometry_values(setup: Setup) -> np.ndarray:
    """The setup's geometry in the units of :data:`GEOMETRY_PARAMETERS`, shape (SHARED_SIZE,).

    The values that the changes add to: the edge angle (deg), light and eye
    radii, the camera's centre in the eye frame, its principal point and
    distortion coefficients, the insertion point, the beams' tilt (deg); 0 for the rotation and the
    focal length's percentage (changes only).
    """
    camera = setup.camera
    values = np.zeros(SHARED_SIZE)
    values[_EDGE] = np.degrees(edge_angle(setup))
    values[_LIGHT] = setup.instrument.light_radius_mm
    values[_RADIUS] = setup.eye.radius_mm
    values[_CAMERA + 3 : _CAMERA + 6] = camera.center_in_eye
    values[_CAMERA + 7 : _CAMERA + 9] = camera.principal_point_px
    values[_CAMERA + 9 : _CAMERA_END] = camera.distortion_coefficients[:5]
    values[_INSERTION:_TILT] = setup.instrument.insertion_in_eye
    values[_TILT] = setup.instrument.beam_tilt_deg
    return values


def setup_with_geometry(setup: Setup, shared: np.ndarray) -> Setup:
    """The setup with the geometry's changes ``shared`` (SHARED_SIZE,), engine units, in place.

    A changed camera is written as a calibrated one (OpenCV's terms); a light
    radius fitted below zero is a point (0).
    """
    shared = np.asarray(shared, dtype=float)
    camera = setup.camera
    if np.any(shared[_CAMERA:_CAMERA_END] != 0.0):
        camera = camera_of_model(camera, perturbed_model(camera_model(camera), shared[_CAMERA:_CAMERA_END]))
    x, y, z = (float(v) for v in setup.instrument.insertion_in_eye + shared[_INSERTION:_TILT])
    instrument = replace(
        setup.instrument,
        edge_half_angle_deg=float(np.degrees(edge_angle(setup) + shared[_EDGE])),
        light_radius_mm=max(float(setup.instrument.light_radius_mm + shared[_LIGHT]), 0.0),
        insertion_point_mm=(x, y, z),
        beam_tilt_deg=float(setup.instrument.beam_tilt_deg + np.degrees(shared[_TILT])),
    )
    eye = replace(setup.eye, radius_mm=float(setup.eye.radius_mm + shared[_RADIUS]))
    return replace(setup, camera=camera, eye=eye, instrument=instrument)


def geometry_to_file_units(values: np.ndarray) -> np.ndarray:
    """Shared parameters (..., SHARED_SIZE) from engine units to those of :data:`GEOMETRY_PARAMETERS`."""
    return np.asarray(values, dtype=float) / _TO_ENGINE


@lru_cache(maxsize=32)
def geometry_covariance(setup: Setup, *, one_frame: bool = True) -> np.ndarray:
    """How well the setup's geometry is known: the shared parameters' covariance, engine units, (SHARED_SIZE,)*2.

    ``[calibration]``'s covariance for the parameters it lists, ``[uncertainty]``
    for the others, and with ``one_frame`` the edge model's error in one
    frame: the one the calibration measured, at least :data:`EDGE_MODEL_SIGMA`
    (a pose's; a calibration over many frames measures that error itself).
    Computed once per setup (every tracked frame asks): the array is read-only.
    """
    covariance = np.diag(prior_sigmas(setup) ** 2)
    record = setup.calibration
    if record.parameters:
        index = [GEOMETRY_PARAMETERS.index(name) for name in record.parameters]
        scale = _TO_ENGINE[index]
        block = np.array(record.covariance, dtype=float) * np.outer(scale, scale)
        covariance[index, :] = 0.0
        covariance[:, index] = 0.0
        covariance[np.ix_(index, index)] = block
    if one_frame:
        covariance[_EDGE, _EDGE] += max(EDGE_MODEL_SIGMA, np.radians(record.frame_edge_sigma_deg)) ** 2
    covariance.setflags(write=False)
    return covariance
