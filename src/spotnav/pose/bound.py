"""The Cramer-Rao bound of a pose: how well any unbiased localizer can know it from one frame.

The frame's pixels are independent, each Gaussian about the photometric model of
:mod:`spotnav.optics.frame_model` (the light's profile, the lens's blur, the clip, the response, shot, read and
rounding noise). Their Fisher information about the pose's parameters ``t`` is

    F = sum_p  w_p (f'_p dx_p/dt) (f'_p dx_p/dt)^T                      (docs/methods.md, "The bound")

and the covariance of any unbiased estimate is at least ``F^-1``. The parameters are the tip (mm), the axis
(its small tilts toward its perpendiculars ``e1``, ``e2`` of
:func:`~spotnav.setup.geometry.orthonormal_basis`, radians; or none, when the axis runs through the insertion
point), the roll of several beams (radians) and the log of the light's power: a localizer knows neither the
roll nor the power, so both are nuisances that the bound includes. The derivatives are central differences of
the model about the pose.

Assumptions: the model is the world (the retina's albedo, the camera and the eye are known; no fault but the
lens's defocus), the noise is white from pixel to pixel, and the frame is not blurred after its encoding.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spotnav.optics.frame_model import FrameModel, PixelInformation, code_information
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose, beam_axes, normalize, orthonormal_basis

__all__ = [
    "BOUND_STATUSES",
    "PoseBound",
    "PoseInformation",
    "PoseParameters",
    "pose_bound",
    "pose_information",
    "pose_jacobian",
]

BOUND_STATUSES = ("ok", "no_light", "undetermined", "hard_edge", "outside_eye")
_TIP_STEP_MM = 1e-4
_ANGLE_STEP = 1e-5  # radians
_MAX_CONDITION = 1e14  # information less well conditioned is singular: the light does not fix the pose


@dataclass(frozen=True)
class PoseParameters:
    """How a vector of parameters ``t`` moves the light about a reference pose.

    ``t = (tip_x, tip_y, tip_z[, tilt_e1, tilt_e2][, roll], log_power)``: mm, radians and the natural log
    of the power over the setup's.

    Attributes
    ----------
    reference : InstrumentPose
        The pose at ``t = (tip, 0, ..., 0)``.
    setup : Setup
        Gives the beams, their tilt, the power and the insertion point.
    through_insertion : bool
        The axis runs from the insertion point to the tip (no axis parameters).
    """

    reference: InstrumentPose
    setup: Setup
    through_insertion: bool

    @property
    def names(self) -> tuple[str, ...]:
        """The parameters' names, in order."""
        axis = () if self.through_insertion else ("tilt_e1", "tilt_e2")
        roll = ("roll",) if self.setup.instrument.beam_count > 1 else ()
        return ("tip_x_mm", "tip_y_mm", "tip_z_mm", *axis, *roll, "log_power")

    @property
    def start(self) -> np.ndarray:
        """``t`` of the reference pose, shape (k,)."""
        values = np.zeros(len(self.names))
        values[:3] = self.reference.tip_in_eye
        return values

    def steps(self) -> np.ndarray:
        """Each parameter's central-difference step, shape (k,)."""
        return np.array([_TIP_STEP_MM] * 3 + [_ANGLE_STEP] * (len(self.names) - 3))

    def pose(self, values: np.ndarray) -> tuple[InstrumentPose, float]:
        """The pose and roll (radians) of ``values``."""
        tip = values[:3]
        if self.through_insertion:
            axis = tip - self.setup.instrument.insertion_in_eye
        else:
            e1, e2 = orthonormal_basis(self.reference.axis)
            axis = self.reference.axis + values[3] * e1 + values[4] * e2
        roll = float(values[-2]) if self.setup.instrument.beam_count > 1 else 0.0
        return InstrumentPose(tip, normalize(axis)), roll

    def light(self, model: FrameModel, values: np.ndarray) -> np.ndarray:
        """The spots' linear light at ``values`` in the model's box, (h, w, 3)."""
        pose, roll = self.pose(values)
        instrument = self.setup.instrument
        axes = beam_axes(pose.axis, instrument.beam_count, instrument.beam_tilt, roll)
        return model.light(pose.tip_in_eye, axes, self.setup.light.power_w * float(np.exp(values[-1])))


def pose_jacobian(model: FrameModel, parameters: PoseParameters, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The spots' light at ``values`` and its derivatives by the parameters.

    Returns
    -------
    light : ndarray, shape (h, w, 3)
        Linear light, without the background.
    jacobian : ndarray, shape (h * w * 3, k)
        ``d light / d t`` (per mm, per radian, per unit of log power).
    """
    light = parameters.light(model, values)
    columns = []
    for index, step in enumerate(parameters.steps()[:-1]):
        shift = np.zeros_like(values)
        shift[index] = step
        ahead, behind = parameters.light(model, values + shift), parameters.light(model, values - shift)
        columns.append(((ahead - behind) / (2.0 * step)).ravel())
    columns.append(light.ravel())  # d light / d log(power)
    return light, np.stack(columns, axis=1)


@dataclass(frozen=True)
class PoseInformation:
    """The frame's information about the pose at some parameters (:func:`pose_information`).

    Attributes
    ----------
    light : ndarray, shape (h, w, 3)
        The spots' linear light there, without the background.
    codes_jacobian : ndarray, shape (h * w * 3, k)
        ``d code / d t``: the response's slope times ``d light / d t``.
    pixel : PixelInformation
        Each pixel's weight, slope and unclipped share.
    information : ndarray, shape (k, k)
        ``sum_p weight_p (d code_p / d t)(d code_p / d t)^T``.
    """

    light: np.ndarray
    codes_jacobian: np.ndarray
    pixel: PixelInformation
    information: np.ndarray

    def covariance(self) -> np.ndarray | None:
        """The information's inverse, or ``None`` when it is singular (the light does not fix every parameter)."""
        if not np.all(np.isfinite(self.information)) or np.linalg.cond(self.information) > _MAX_CONDITION:
            return None
        covariance: np.ndarray = np.linalg.inv(self.information)
        return covariance if np.all(np.diag(covariance) > 0) else None


def pose_information(model: FrameModel, parameters: PoseParameters, values: np.ndarray) -> PoseInformation:
    """The Fisher information of the pose's parameters at ``values`` (module docstring)."""
    light, jacobian = pose_jacobian(model, parameters, values)
    pixel = code_information(parameters.setup, (model.background + light).ravel())
    codes_jacobian = jacobian * pixel.slope[:, None]
    information = codes_jacobian.T @ (codes_jacobian * pixel.weight[:, None])
    return PoseInformation(light, codes_jacobian, pixel, information)


@dataclass(frozen=True)
class PoseBound:
    """The Cramer-Rao bound of one pose, or why there is none.

    Attributes
    ----------
    status : str
        One of :data:`BOUND_STATUSES`: ``ok``; ``no_light`` (no spot in the frame); ``undetermined`` (the light
        does not fix every parameter: its information is singular); ``hard_edge`` (``light.blend = 0``, which the
        model does not resolve); ``outside_eye`` (the tip is not inside the eye).
    tip_sd_mm : ndarray, shape (3,)
        The bound's standard deviation of the tip along eye x, y and z, mm.
    axis_sd_deg : ndarray, shape (2,)
        Of the axis's tilt toward its perpendiculars ``e1`` and ``e2``, degrees.
    covariance : ndarray, shape (k, k)
        The inverse of the information, in the units of ``parameters``.
    parameters : tuple of str
        The parameters' names (:class:`PoseParameters`).
    pixels : int
        Pixels (times channels) that carry information.
    clipped_share : float
        The share of the spots' information that the clip took away.
    detail : str
        Why there is no bound.
    """

    status: str
    tip_sd_mm: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    axis_sd_deg: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    parameters: tuple[str, ...] = ()
    pixels: int = 0
    clipped_share: float = float("nan")
    detail: str = ""

    def __post_init__(self) -> None:
        if self.status not in BOUND_STATUSES:
            raise ValueError(f"status must be one of {BOUND_STATUSES}, got {self.status!r}")

    @property
    def ok(self) -> bool:
        """Whether there is a bound."""
        return self.status == "ok"

    @property
    def tip_mm(self) -> float:
        """The tip's bound, total: the root of the summed variances, mm."""
        return float(np.sqrt(np.sum(self.tip_sd_mm**2)))

    @property
    def axis_deg(self) -> float:
        """The axis's bound, total: the root of the summed variances, degrees."""
        return float(np.sqrt(np.sum(self.axis_sd_deg**2)))


def pose_bound(setup: Setup, pose: InstrumentPose, *, through_insertion: bool = True) -> PoseBound:
    """The Cramer-Rao bound of ``pose`` in ``setup``'s world, from one frame.

    Parameters
    ----------
    setup : Setup
        The world: camera, eye, light, render settings (noise, response, bits, exposure).
    pose : InstrumentPose
        True tip and axis, eye frame.
    through_insertion : bool
        The localizer knows that the axis runs through the insertion point (as the precise method does by
        default): the axis is no parameter, its bound follows from the tip's.

    Returns
    -------
    PoseBound
    """
    if setup.light.blend == 0.0:
        detail = "a hard edge (light.blend = 0): its information lies in the pixels it cuts, which the model does not "
        detail += "resolve"
        return PoseBound("hard_edge", detail=detail)
    radius = setup.true_radius_mm
    if setup.world.surface == "sphere" and np.linalg.norm(pose.tip_in_eye - [0.0, 0.0, radius]) >= radius:
        return PoseBound("outside_eye", detail=f"the tip lies outside the eye (radius {radius:g} mm)")
    if through_insertion:
        pose = InstrumentPose.through_insertion(pose.tip_in_eye, setup.instrument.insertion_in_eye)
    model = FrameModel(setup, pose)
    if model.box is None or setup.light.power_w == 0.0:
        return PoseBound("no_light", detail="no light reaches the retina that the camera sees")
    parameters = PoseParameters(pose, setup, through_insertion)
    found = pose_information(model, parameters, parameters.start)
    covariance = found.covariance()
    if covariance is None:
        detail = "the light does not fix every parameter of the pose (its information is singular)"
        return PoseBound("undetermined", parameters=parameters.names, detail=detail)
    variances = np.diag(covariance)
    tip_sd = np.sqrt(variances[:3])
    if through_insertion:
        arm = pose.tip_in_eye - setup.instrument.insertion_in_eye
        e1, e2 = orthonormal_basis(pose.axis)
        tilt = np.stack([e1, e2]) / np.linalg.norm(arm)  # a move of the tip tilts the axis by its part along e1, e2
        axis_covariance = tilt @ covariance[:3, :3] @ tilt.T
    else:
        axis_covariance = covariance[3:5, 3:5]
    tip_information = found.codes_jacobian[:, :3] ** 2
    kept = float(np.sum(tip_information * found.pixel.weight[:, None]))
    total = float(np.sum(tip_information * found.pixel.noise_weight[:, None]))
    return PoseBound(
        "ok",
        tip_sd_mm=tip_sd,
        axis_sd_deg=np.degrees(np.sqrt(np.diag(axis_covariance))),
        covariance=covariance,
        parameters=parameters.names,
        pixels=int(np.count_nonzero(np.any(found.codes_jacobian * found.pixel.weight[:, None] != 0.0, axis=1))),
        clipped_share=float(1.0 - kept / total) if total > 0 else 0.0,
    )
