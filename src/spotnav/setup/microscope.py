"""The setup's ``[camera]`` section: the microscope's camera, the thesis's ideal pinhole or a calibrated one.

:class:`Camera` checks its keys as it is built (each error names the key and the allowed range) and derives from
either form the same terms, OpenCV's: camera matrix, distortion coefficients, rotation and translation. Lengths in
millimetres, angles in degrees, as in the setup file.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from spotnav.setup.values import (
    SetupError,
    hash_once,
    in_range,
    integer,
    matrix3,
    number,
    read_only,
    state_without_hash,
    vector3,
)

__all__ = ["CALIBRATED_KEYS", "DISTORTION_COUNTS", "IDEAL_KEYS", "IDEAL_ROTATION", "RESPONSES", "Camera"]

RESPONSES = ("srgb", "linear", "agx")  # besides a gamma number: how pixel values relate to light
IDEAL_ROTATION = ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0))  # eye frame to the ideal camera's frame
DISTORTION_COUNTS = (4, 5, 8, 12, 14)  # OpenCV's distortion vector lengths
CALIBRATED_KEYS = ("matrix", "distortion", "rotation", "translation_mm")
IDEAL_KEYS = ("sensor_width_mm", "focal_length_mm", "distance_mm")
_MAX_LENGTH_MM = 1e6  # a camera's lengths and distance: up to a kilometre
# The focal length over the image's width (fx / width_px): a field of view from 176 deg down to 0.006 deg.
_FOCAL_PER_WIDTH = (0.01, 1e4)
_ORTHONORMAL_TOLERANCE = 1e-6
_MAX_APERTURE_MM = 1000.0  # an entrance pupil up to a metre across: any lens's


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
        curve, :func:`spotnav.optics.response.encode_light`), or a number ``g``: values
        proportional to light ``** (1 / g)``, ``g`` in [0.2, 5]. ``None``: not
        stated; frames are read as sRGB (:attr:`pixel_response`).
    aperture_mm : float or None
        The lens's entrance pupil diameter, mm, for its depth of field: a retina point off the focal plane spreads
        its light over a disk (:func:`spotnav.optics.defocus.light_blur_px`). 0: a pinhole, every point in focus;
        ``None`` (the default): not stated, read as a pinhole (:attr:`lens_aperture_mm`), and ``spotnav calibrate``
        measures it where known frames' spots clip. In [0, 1000].
    focus_distance_mm : float or None
        The depth (along the optical axis, mm) the lens is focused at; ``None`` (the default): the camera's depth
        of the pole (:attr:`focus_depth_mm`). In (0, 1e6].
    """

    width_px: int = 5000
    height_px: int = 5000
    sensor_width_mm: float | None = 36.0
    focal_length_mm: float | None = 300.0
    distance_mm: float | None = 110.0
    # Rows and translation of any length as given (calibrated() passes its arrays'): __post_init__ checks for 3.
    matrix: tuple[tuple[float, ...], ...] | None = None
    distortion: tuple[float, ...] | None = None
    rotation: tuple[tuple[float, ...], ...] | None = None
    translation_mm: tuple[float, ...] | None = None
    response: str | float | None = None
    aperture_mm: float | None = None
    focus_distance_mm: float | None = None

    __hash__ = hash_once
    __getstate__ = state_without_hash

    def __post_init__(self) -> None:
        for name in ("width_px", "height_px"):
            value = integer(f"camera.{name}", getattr(self, name))
            in_range(f"camera.{name}", value, 16, 20000)
        if isinstance(self.response, str):
            if self.response not in RESPONSES:
                raise SetupError(
                    f"camera.response = {self.response!r} is not allowed, "
                    "allowed 'srgb', 'linear', 'agx' or a gamma number"
                )
        elif self.response is not None:
            in_range("camera.response", number("camera.response", self.response), 0.2, 5.0)
            object.__setattr__(self, "response", float(self.response))
        if self.aperture_mm is not None:
            aperture = number("camera.aperture_mm", self.aperture_mm)
            in_range("camera.aperture_mm", aperture, 0.0, _MAX_APERTURE_MM)
            object.__setattr__(self, "aperture_mm", float(aperture))
        if self.focus_distance_mm is not None:
            focus = number("camera.focus_distance_mm", self.focus_distance_mm)
            in_range("camera.focus_distance_mm", focus, 0.0, _MAX_LENGTH_MM, low_open=True)
            object.__setattr__(self, "focus_distance_mm", float(focus))
        given = [name for name in CALIBRATED_KEYS if getattr(self, name) is not None]
        if given:
            missing = [name for name in CALIBRATED_KEYS if name not in given]
            if missing:
                raise SetupError(
                    f"camera.{missing[0]} is missing: a calibrated camera gives "
                    f"{', '.join('camera.' + k for k in CALIBRATED_KEYS)} together"
                )
            for name in IDEAL_KEYS:  # the calibrated camera replaces the ideal one's keys
                object.__setattr__(self, name, None)
            self._check_calibrated()
        else:
            for name in IDEAL_KEYS:
                length = number(f"camera.{name}", getattr(self, name))
                in_range(f"camera.{name}", length, 0.0, _MAX_LENGTH_MM, low_open=True)
            ratio = self.focal_length_mm / self.sensor_width_mm  # type: ignore[operator]
            in_range("camera.focal_length_mm / camera.sensor_width_mm", ratio, *_FOCAL_PER_WIDTH)

    def _check_calibrated(self) -> None:
        matrix = matrix3("camera.matrix", self.matrix)
        (fx, skew, cx), (zero_a, fy, cy), last = matrix
        for name, value in (("camera.matrix[0][0] (fx)", fx), ("camera.matrix[1][1] (fy)", fy)):
            in_range(name, value, *(bound * self.width_px for bound in _FOCAL_PER_WIDTH))
        if skew != 0.0 or zero_a != 0.0 or last != (0.0, 0.0, 1.0):
            raise SetupError(f"camera.matrix must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {self.matrix!r}")
        in_range("camera.matrix[0][2] (cx)", cx, -0.5, self.width_px - 0.5)
        in_range("camera.matrix[1][2] (cy)", cy, -0.5, self.height_px - 0.5)
        distortion = self.distortion
        if not isinstance(distortion, list | tuple) or len(distortion) not in DISTORTION_COUNTS:
            counts = ", ".join(map(str, DISTORTION_COUNTS))
            raise SetupError(
                f"camera.distortion must be a list of {counts} numbers (OpenCV's order), got {distortion!r}"
            )
        distortion = tuple(number(f"camera.distortion[{i}]", v) for i, v in enumerate(distortion))
        rotation = matrix3("camera.rotation", self.rotation)
        array = np.array(rotation)
        if not (np.allclose(array @ array.T, np.eye(3), atol=_ORTHONORMAL_TOLERANCE) and np.linalg.det(array) > 0):
            raise SetupError(
                "camera.rotation must be a rotation matrix (orthonormal to 1e-6, determinant +1), "
                f"got {self.rotation!r}"
            )
        translation = vector3("camera.translation_mm", self.translation_mm)
        for index, value in enumerate(translation):
            in_range(f"camera.translation_mm[{index}]", value, -_MAX_LENGTH_MM, _MAX_LENGTH_MM)
        for name, checked in (
            ("matrix", matrix),
            ("distortion", distortion),
            ("rotation", rotation),
            ("translation_mm", translation),
        ):
            object.__setattr__(self, name, checked)

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
            return read_only(np.array(self.matrix, dtype=float))
        focal = self.focal_length_mm * self.width_px / self.sensor_width_mm  # type: ignore[operator]
        cx, cy = (self.width_px - 1) / 2.0, (self.height_px - 1) / 2.0
        return read_only(np.array([[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]]))

    @cached_property
    def distortion_coefficients(self) -> np.ndarray:
        """OpenCV's distortion coefficients padded with zeros to all 14, shape (14,)."""
        coefficients = np.zeros(14)
        if self.distortion is not None:
            coefficients[: len(self.distortion)] = self.distortion
        return read_only(coefficients)

    @cached_property
    def rotation_to_camera(self) -> np.ndarray:
        """``R``, eye frame to OpenCV's camera frame, shape (3, 3)."""
        return read_only(np.array(self.rotation if self.rotation is not None else IDEAL_ROTATION, dtype=float))

    @cached_property
    def translation_to_camera_mm(self) -> np.ndarray:
        """``t`` of ``x_cam = R x_eye + t``, shape (3,), mm."""
        if self.translation_mm is not None:
            return read_only(np.array(self.translation_mm, dtype=float))
        return read_only(np.array([0.0, 0.0, self.distance_mm]))

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
        return read_only(-self.rotation_to_camera.T @ self.translation_to_camera_mm)

    @property
    def lens_aperture_mm(self) -> float:
        """The entrance pupil's diameter the frames are drawn and read with, mm: :attr:`aperture_mm`, 0 unstated."""
        return 0.0 if self.aperture_mm is None else self.aperture_mm

    @cached_property
    def focus_depth_mm(self) -> float:
        """The depth the lens is focused at, mm: :attr:`focus_distance_mm`, or the camera's depth of the pole."""
        if self.focus_distance_mm is not None:
            return self.focus_distance_mm
        return float(self.translation_to_camera_mm[2])

    def with_lens_of(self, other: Camera) -> Camera:
        """This camera with ``other``'s depth of field (:attr:`aperture_mm`, :attr:`focus_distance_mm`)."""
        return replace(self, aperture_mm=other.aperture_mm, focus_distance_mm=other.focus_distance_mm)

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
        ).with_lens_of(self)

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
        ).with_lens_of(self)
