"""Localize the instrument tip in one camera frame.

Every method returns a :class:`PoseEstimate`: a pose with status ``ok``, or a
status that says why there is none. No method makes up a pose.

Statuses
--------
``ok``
    A pose was found.
``no_spot``
    No spot stands out from the background.
``ambiguous``
    More spots than beams.
``clipped``
    A spot reaches the image's border or leaves the retina.
``wrong_size``
    The image is not the camera's size.
``unreliable``
    A fit was found but fails a consistency check (see ``detail``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from spotnav.camera import unproject_pixels_to_sphere
from spotnav.config import Setup
from spotnav.detect import detect_spots_otsu
from spotnav.geometry import normalize
from spotnav.reconstruct import apex_candidates, choose_by_insertion

__all__ = ["METHODS", "STATUSES", "PoseEstimate", "localize", "localize_thesis"]

STATUSES = ("ok", "no_spot", "ambiguous", "clipped", "wrong_size", "unreliable", "unreadable")


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
        Human-readable reason for a status other than ``ok``.
    """

    status: str
    tip_in_eye: np.ndarray | None = None
    axis: np.ndarray | None = None
    spots: int = 0
    detail: str = ""

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {STATUSES}, got {self.status!r}")
        if (self.status == "ok") != (self.tip_in_eye is not None and self.axis is not None):
            raise ValueError("a pose is given exactly when status is 'ok'")

    @property
    def ok(self) -> bool:
        """Whether a pose was found."""
        return self.status == "ok"


def _check_size(image: np.ndarray, setup: Setup) -> PoseEstimate | None:
    expected = (setup.camera.height_px, setup.camera.width_px)
    if image.shape[:2] != expected:
        return PoseEstimate(
            "wrong_size",
            detail=f"image is {image.shape[1]}x{image.shape[0]} px, "
            f"the setup's camera is {expected[1]}x{expected[0]} px",
        )
    return None


def localize_thesis(image: np.ndarray, setup: Setup) -> PoseEstimate:
    """The thesis's Algorithm 1 (one beam), with the candidate chosen by the insertion point.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3|4), uint8 or uint16
        Camera frame, RGB(A) or grey.
    setup : Setup
        Only ``eye``, ``camera`` and ``instrument`` are used.
    """
    wrong = _check_size(image, setup)
    if wrong is not None:
        return wrong
    if setup.instrument.beam_count != 1:
        raise ValueError("localize_thesis handles one beam; instrument.beam_count is 3")
    detection = detect_spots_otsu(image)
    if not detection.spots:
        return PoseEstimate(
            "no_spot", detail=f"no region brighter than the background (contrast {detection.contrast:.1f})"
        )
    if len(detection.spots) > 1:
        return PoseEstimate("ambiguous", spots=len(detection.spots), detail=f"{len(detection.spots)} spots, expected 1")
    spot = detection.spots[0]
    if spot.touches_border:
        return PoseEstimate("clipped", spots=1, detail="the spot reaches the image border")
    radius = setup.eye.radius_mm
    points = unproject_pixels_to_sphere(setup.camera, spot.contour_px, radius)
    if not np.all(np.isfinite(points)):
        return PoseEstimate("clipped", spots=1, detail="part of the spot lies off the retina model")
    candidates = apex_candidates(points, setup.eye.center_in_eye, setup.instrument.beam_half_angle)
    index, _ = choose_by_insertion(candidates, setup.instrument.insertion_in_eye)
    tip = candidates.apexes[index]
    if not setup.contains_point(tip):
        return PoseEstimate("unreliable", spots=1, detail="the fitted apex lies outside the eye")
    axis = normalize(tip - setup.instrument.insertion_in_eye)  # the thesis's axis
    return PoseEstimate("ok", tip_in_eye=tip, axis=axis, spots=1)


METHODS: dict[str, Callable[[np.ndarray, Setup], PoseEstimate]] = {"thesis": localize_thesis}
DEFAULT_METHOD = "thesis"


def localize(image: np.ndarray, setup: Setup, method: str = DEFAULT_METHOD) -> PoseEstimate:
    """Localize the tip with a named method (see :data:`METHODS`).

    Raises
    ------
    ValueError
        For an unknown method.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    return METHODS[method](image, setup)
