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
``too_few_spots``
    Fewer whole spots than the method needs (three beams need two).
``clipped``
    A spot reaches the image's border or leaves the retina.
``wrong_size``
    The image is not the camera's size.
``unreliable``
    A fit was found but fails a consistency check (see ``detail``).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from spotnav.camera import unproject_pixels_to_plane, unproject_pixels_to_sphere
from spotnav.config import Setup
from spotnav.detect import Spot, SpotDetection, detect_spots_otsu
from spotnav.geometry import normalize
from spotnav.reconstruct import ConeCandidates, apex_candidates, choose_by_insertion, sphere_normal

__all__ = [
    "METHODS",
    "STATUSES",
    "PoseEstimate",
    "fit_height_correction",
    "localize",
    "localize_thesis",
    "locate_from_spots",
    "spot_candidates",
]

STATUSES = ("ok", "no_spot", "ambiguous", "too_few_spots", "clipped", "wrong_size", "unreliable", "unreadable")


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
    """The thesis's method: Algorithm 1 (one beam) or Algorithm 2 (three beams).

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
    return locate_from_spots(detect_spots_otsu(image), setup)


def spot_candidates(spot: Spot, setup: Setup, surface: str = "sphere") -> ConeCandidates | None:
    """Both apex candidates of one spot (Algorithm 1 after detection).

    Parameters
    ----------
    spot : Spot
    setup : Setup
        The eye, camera and instrument (with its height correction).
    surface : str
        ``"sphere"``: the retina of ``eye.radius_mm``. ``"plane"``: the plane
        ``z = 0``, the thesis's ellipse test (section 6.2).

    Returns
    -------
    ConeCandidates or None
        ``None`` when the spot is cut by the border or the retina's edge.
    """
    if spot.touches_border:
        return None
    if surface == "plane":
        points = unproject_pixels_to_plane(setup.camera, spot.contour_px)
        normal = np.array([0.0, 0.0, 1.0])
    else:
        points = unproject_pixels_to_sphere(setup.camera, spot.contour_px, setup.eye.radius_mm)
        if not np.all(np.isfinite(points)):
            return None
        normal = sphere_normal(points, setup.eye.center_in_eye)
    return apex_candidates(points, normal, setup.instrument.beam_half_angle, setup.instrument.height_correction)


def _closest_set(candidates: list[ConeCandidates]) -> np.ndarray:
    """One apex per contour, the combination with the smallest summed pairwise distance, shape (n, 3)."""
    best, best_spread = None, np.inf
    for choice in itertools.product((0, 1), repeat=len(candidates)):
        apexes = np.array([c.apexes[i] for c, i in zip(candidates, choice, strict=True)])
        spread = sum(np.linalg.norm(p - q) for p, q in itertools.combinations(apexes, 2))
        if spread < best_spread:
            best, best_spread = apexes, spread
    assert best is not None
    return best


def locate_from_spots(detection: SpotDetection, setup: Setup, surface: str = "sphere") -> PoseEstimate:
    """The thesis's reconstruction from detected spots (Algorithms 1 and 2).

    One beam: the spot's two apex candidates, the one whose cone axis runs
    along its line from the insertion point. Three beams: two candidates per
    spot, the combination (one per spot) with the smallest spread, and its
    coordinate-wise median; two visible spots still give a pose (their mean),
    with ``spots = 2``. The instrument's axis comes from the insertion point.
    ``instrument.height_correction`` (section 5.5) scales every triangle.
    ``surface`` is that of :func:`spot_candidates`.
    """
    beams = setup.instrument.beam_count
    spots = detection.spots
    if not spots:
        return PoseEstimate(
            "no_spot", detail=f"no region brighter than the background (contrast {detection.contrast:.1f})"
        )
    if len(spots) > beams:
        return PoseEstimate("ambiguous", spots=len(spots), detail=f"{len(spots)} spots, expected {beams}")
    usable = [c for c in (spot_candidates(s, setup, surface) for s in spots) if c]
    needed = 1 if beams == 1 else 2
    if len(usable) < needed:
        if len(usable) < len(spots):
            return PoseEstimate(
                "clipped", spots=len(spots), detail="a spot reaches the image border or the retina's edge"
            )
        return PoseEstimate("too_few_spots", spots=len(spots), detail=f"{len(spots)} of {beams} spots, need {needed}")
    if beams == 1:
        index, _ = choose_by_insertion(usable[0], setup.instrument.insertion_in_eye)
        tip = usable[0].apexes[index]
    else:
        tip = np.median(_closest_set(usable), axis=0)  # Algorithm 2; the median of two is their mean
    if not setup.contains_point(tip):
        return PoseEstimate("unreliable", spots=len(usable), detail="the fitted apex lies outside the eye")
    axis = normalize(tip - setup.instrument.insertion_in_eye)  # the thesis's axis
    detail = f"{len(usable)} of {beams} spots" if len(usable) < beams else ""
    return PoseEstimate("ok", tip_in_eye=tip, axis=axis, spots=len(usable), detail=detail)


def fit_height_correction(image: np.ndarray, setup: Setup, tip_in_eye: np.ndarray) -> float:
    """Section 5.5's factor from one frame with the tip at a known position.

    The known height of the tip above each spot's fitting plane divided by the
    reconstructed height ``s2``, averaged over the visible spots.

    Raises
    ------
    ValueError
        When the frame shows no usable spot.
    """
    wrong = _check_size(image, setup)
    if wrong is not None:
        raise ValueError(wrong.detail)
    detection = detect_spots_otsu(image)
    if len(detection.spots) > setup.instrument.beam_count:
        raise ValueError(f"the calibration frame shows {len(detection.spots)} spots")
    plain = replace(setup, instrument=replace(setup.instrument, height_correction=1.0))
    fits = [c for c in (spot_candidates(s, plain) for s in detection.spots) if c]
    if not fits:
        raise ValueError("the calibration frame shows no whole spot")
    tip_in_eye = np.asarray(tip_in_eye, dtype=float)
    factors = [float((tip_in_eye - c.plane_origin_in_eye) @ c.plane_normal_in_eye) / c.s2 for c in fits]
    return float(np.mean(factors))


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
