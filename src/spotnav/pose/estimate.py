"""One frame's answer: a pose with its uncertainty, or a status that says why there is none.

Statuses
--------
``ok``
    A pose was found.
``no_spot``
    No spot stands out from the background.
``ambiguous``
    More spots than beams, spots that match no beam order, or (``precise-free``,
    one beam) a cone and its mirror image that fit alike.
``too_few_spots``
    Fewer whole spots than the method needs (three beams need two).
``clipped``
    A spot reaches the image's border or leaves the retina.
``occluded``
    The instrument's shaft hides too much of a spot's edge.
``wrong_size``
    The image is not the camera's size.
``unreliable``
    A fit was found but fails a consistency check (see ``detail``).
``blurred``
    A spot's edge is blurred so that where the blur acted (in light, or on
    the encoded frame) leaves it too uncertain.
``uncalibrated``
    A fit was found, but the setup's geometry is known too poorly to back it:
    its uncertainty alone puts the tip's ``sigma_mm`` over the limit (calibrate).
``miscalibrated``
    The edges contradict the setup's geometry (three beams: the axis they show
    misses the insertion point).
``mismatch``
    The fit leaves residuals that the edge's noise does not explain: the
    setup's light or geometry is not the frame's (calibrate), or the spot is
    disturbed as no model here says (see ``detail``).
``unreadable``
    The image file could not be read.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["STATUSES", "PoseEstimate", "within_sigmas"]

STATUSES = (
    "ok",
    "no_spot",
    "ambiguous",
    "too_few_spots",
    "clipped",
    "occluded",
    "wrong_size",
    "unreliable",
    "blurred",
    "uncalibrated",
    "miscalibrated",
    "mismatch",
    "unreadable",
)


def within_sigmas(error_mm: ArrayLike, sigma_mm: ArrayLike, sigmas: float = 3.0) -> np.ndarray:
    """Whether a tip's 3-D error is within ``sigmas`` of its 3-D standard error, ``sqrt(3) * sigma_mm``.

    ``sigma_mm`` is per axis (the root of a third of the tip covariance's trace), so the 3-D error's RMS is
    ``sqrt(3)`` times it. Compared with ``sigma_mm`` itself, a 3-D distance fails an honest sigma on 8 % of the
    frames whose error lies along one direction (the height, as a small spot's does: issue 61's first try), and on
    3 % of those where it is isotropic.

    Parameters
    ----------
    error_mm, sigma_mm : array_like
        Tip errors (3-D distance to the truth) and their ``sigma_mm``, mm, broadcast together.
    sigmas : float
        How many standard errors.

    Returns
    -------
    ndarray of bool
    """
    return np.asarray(np.asarray(error_mm) <= sigmas * np.sqrt(3.0) * np.asarray(sigma_mm), dtype=bool)


@dataclass(frozen=True)
class PoseEstimate:
    """One frame's answer.

    Attributes
    ----------
    status : str
        One of :data:`STATUSES`.
    tip_in_eye : ndarray, shape (3,), or None
        Estimated tip, mm; ``None`` unless ``status == "ok"``.
    axis : ndarray, shape (3,), or None
        Estimated instrument axis (unit, insertion point toward tip).
    spots : int
        Number of spots used.
    detail : str
        Human-readable reason for a status other than ``ok``, or a remark.
    sigma_mm : float
        1-sigma tip uncertainty per axis (the root of a third of the tip
        covariance's trace), mm (precise method; NaN otherwise).
    rms_px : float
        RMS distance of the edge points from the fitted cones, pixels
        (approximate: the angular residual times the range over the pixel size).
    fit_ratio : float
        The fit's own test: its RMS residual over the one its points' noise
        explains (about 1 where the model fits; precise method, NaN otherwise).
    other_axis : ndarray, shape (3,), or None
        The precise method's cross-check: the axis fitted without the insertion
        point (or with it, when the pose was fitted without).
    roll : float
        Three beams: the fitted roll of beam 0 about the axis from the
        contract's zero roll, radians (0 for one beam and the thesis method).
    """

    status: str
    tip_in_eye: np.ndarray | None = None
    axis: np.ndarray | None = None
    spots: int = 0
    detail: str = ""
    sigma_mm: float = float("nan")
    rms_px: float = float("nan")
    fit_ratio: float = float("nan")
    other_axis: np.ndarray | None = None
    roll: float = 0.0

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {STATUSES}, got {self.status!r}")
        if (self.status == "ok") != (self.tip_in_eye is not None and self.axis is not None):
            raise ValueError("a pose is given exactly when status is 'ok'")

    @property
    def ok(self) -> bool:
        """Whether a pose was found."""
        return self.status == "ok"

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The tip (mm) and the unit axis of an ``ok`` estimate.

        Raises
        ------
        ValueError
            For an estimate without a pose (a bug in the caller: check :attr:`ok` first).
        """
        if self.tip_in_eye is None or self.axis is None:
            raise ValueError(f"a {self.status!r} estimate has no pose")
        return self.tip_in_eye, self.axis
