"""Fit the photometric model to a frame: the pose whose expected frame the pixels agree with best.

The maximum-likelihood estimate under the model of :mod:`spotnav.optics.frame_model`: Gauss-Newton steps on
the weighted residuals of the pixels' codes, with the bound's parameters and derivatives
(:mod:`spotnav.pose.bound`). It knows what the bound assumes, the retina's albedo among it, so it is the
estimator that reaches the bound where the model is the world; its residuals say where it is not
(``chi2_per_pixel`` over 2: status ``mismatch``). They do not say everything: a setup whose eye radius is 2 %
off leaves them as the noise's while the tip moves by 1-32 um, as the precise method's does. The simulation's
studies use it to show how close to the bound a localizer
can come, from the precise method's pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spotnav.optics.frame_model import FrameModel, expected_codes
from spotnav.pose.bound import PoseParameters, pose_information
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose

__all__ = ["ModelFit", "fit_model_to_frame"]

_MAX_STEPS = 8
_EXTRA_ROUNDS = 2  # rounds after a round that did not settle
# Residuals over twice the noise's: the model is not the world. Where it is, 0.6-1.3 (tests); a frame blurred by
# 1.5 px after its encoding gave 19-51, and the fit's tip 18-35 um off.
_MAX_CHI2 = 2.0
_CONVERGED_MM = 1e-7  # a step that moves the tip less than this ends the fit


@dataclass(frozen=True)
class ModelFit:
    """A pose fitted to a frame's pixels, or why there is none.

    Attributes
    ----------
    status : str
        ``ok``; ``no_light`` (no spot in the model's frame); ``undetermined`` (the light does not fix the pose);
        ``unconverged`` (the steps did not settle: a start too far for the model's pixels, or a model that is not
        the world); ``mismatch`` (the steps settled on residuals the noise does not explain: the model is not the
        world, as for a frame blurred after its encoding).
    pose : InstrumentPose or None
        The fitted pose (``None`` unless ok).
    roll : float
        Of several beams, radians.
    covariance : ndarray, shape (k, k)
        The inverse of the pixels' information where the last round started (the bound there).
    chi2_per_pixel : float
        The weighted residuals' mean square at the fitted pose: about 1 where the model is the world.
    steps : int
        Gauss-Newton steps taken.
    """

    status: str
    pose: InstrumentPose | None = None
    roll: float = 0.0
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    chi2_per_pixel: float = float("nan")
    steps: int = 0

    @property
    def ok(self) -> bool:
        """Whether a pose was fitted."""
        return self.status == "ok"


def fit_model_to_frame(
    image: np.ndarray, setup: Setup, start: InstrumentPose, *, through_insertion: bool = True, rounds: int = 2
) -> ModelFit:
    """The maximum-likelihood pose of ``image`` under ``setup``'s photometric model, from ``start``.

    Parameters
    ----------
    image : ndarray, shape (height_px, width_px, 3)
        The frame as written (codes).
    setup : Setup
        The world the frame shows (its albedo, light, camera and noise).
    start : InstrumentPose
        Where to start (the precise method's pose), eye frame; the model's pixels are those around it.
    through_insertion : bool
        The axis runs through the insertion point (3 unknowns for the tip, with the roll and the power).
    rounds : int
        Fits, each with the model built about the last one's answer: the model's supersampled pixels are the
        renderer's about its pose, and a start a tenth of a pixel off biases the first round's answer by most of
        a sigma. One round serves a start at the true pose. A round that does not settle is followed by another,
        up to two more.

    Returns
    -------
    ModelFit
    """
    if through_insertion:
        start = InstrumentPose.through_insertion(start.tip_in_eye, setup.instrument.insertion_in_eye)
    pose, roll, settled, fit = start, 0.0, 0, ModelFit("no_light")
    for _ in range(rounds + _EXTRA_ROUNDS):
        fit, pose, roll = _fit_about(image, setup, pose, roll, through_insertion)
        if fit.status in ("no_light", "undetermined", "mismatch"):
            return fit
        settled = settled + 1 if fit.ok else 0  # rounds in a row that settled
        if settled >= rounds:
            break
    return fit


def _fit_about(
    image: np.ndarray, setup: Setup, start: InstrumentPose, roll: float, through_insertion: bool
) -> tuple[ModelFit, InstrumentPose, float]:
    """Gauss-Newton steps from ``start`` with the model built about it (:func:`fit_model_to_frame`): the fit, and
    the pose and roll where its steps ended (the next round's start, settled or not)."""
    model = FrameModel(setup, start)
    if model.box is None:
        return ModelFit("no_light"), start, roll
    u0, v0, u1, v1 = model.box
    codes = image[v0:v1, u0:u1].astype(float).ravel()
    parameters = PoseParameters(start, setup, through_insertion)
    values = parameters.start
    if setup.instrument.beam_count > 1:
        values[-2] = roll
    # The chord method: the derivatives at the start serve every step of the round (the next round renews them).
    found = pose_information(model, parameters, values)
    covariance = found.covariance()
    if covariance is None:
        return ModelFit("undetermined"), start, roll
    solve = covariance @ (found.codes_jacobian * found.pixel.weight[:, None]).T
    light, steps, converged = found.light, 0, False
    while steps < _MAX_STEPS and not converged:
        steps += 1
        step = solve @ (codes - expected_codes(setup, (model.background + light).ravel()))
        values = values + step
        light = parameters.light(model, values)
        converged = bool(np.linalg.norm(step[:3]) < _CONVERGED_MM)
    residual = codes - expected_codes(setup, (model.background + light).ravel())
    chi2 = float(np.sum(found.pixel.weight * residual**2) / max(np.count_nonzero(found.pixel.weight > 0), 1))
    pose, roll = parameters.pose(values)
    if not converged:
        return ModelFit("unconverged", chi2_per_pixel=chi2, steps=steps), pose, roll
    if chi2 > _MAX_CHI2:
        return ModelFit("mismatch", chi2_per_pixel=chi2, steps=steps), pose, roll
    return ModelFit("ok", pose, roll, covariance, chi2, steps), pose, roll
