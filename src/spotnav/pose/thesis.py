"""The thesis's method: Algorithms 1 and 2 as written (sections 5.3-5.4), and section 5.5's height correction.

Spots are found by Otsu's threshold (:func:`spotnav.image.spots.detect_spots_otsu`);
each contour is back-projected onto the retina and fitted with an ellipse
whose triangle gives two apex candidates (:mod:`spotnav.pose.reconstruct`). One
beam: the candidate whose cone axis runs along its line from the insertion
point (thesis-notes 6). Three beams: the closest triple and its median.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from spotnav.image.spots import Spot, SpotDetection, detect_spots_otsu
from spotnav.optics.camera import unproject_pixels_to_plane, unproject_pixels_to_sphere
from spotnav.pose.checks import check_image_size
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.reconstruct import ConeCandidates, apex_candidates, choose_by_insertion, sphere_normal
from spotnav.setup.config import Setup
from spotnav.setup.geometry import normalize
from spotnav.setup.sections import check_localized_beams

__all__ = [
    "HeightFactor",
    "ThesisSolution",
    "fit_height_correction",
    "localize_thesis",
    "localize_thesis_with_spots",
    "locate_from_spots",
    "solve_thesis",
    "spot_candidates",
]


def localize_thesis(image: np.ndarray, setup: Setup) -> PoseEstimate:
    """The thesis's method: Algorithm 1 (one beam) or Algorithm 2 (three beams).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3|4), uint8 or uint16
        Camera frame, RGB(A) or grey.
    setup : Setup
        Only ``eye``, ``camera`` and ``instrument`` are used.
    """
    return localize_thesis_with_spots(image, setup)[0]


def localize_thesis_with_spots(image: np.ndarray, setup: Setup) -> tuple[PoseEstimate, SpotDetection | None]:
    """:func:`localize_thesis`, and the spots it detected (None for an image of the wrong size).

    Raises
    ------
    SetupError
        For 2 or 4 beams (simulation only, :func:`~spotnav.setup.sections.check_localized_beams`).
    """
    check_localized_beams(setup.instrument)
    wrong = check_image_size(image, setup)
    if wrong is not None:
        return wrong, None
    detection = detect_spots_otsu(image, response=setup.camera.pixel_response)
    return locate_from_spots(detection, setup), detection


def spot_candidates(spot: Spot, setup: Setup, surface: str = "sphere") -> ConeCandidates:
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
    ConeCandidates
        ``clipped`` when the spot is cut by the border or the retina's edge, ``unreliable`` when no ellipse fits its
        contour.
    """
    if spot.touches_border:
        return ConeCandidates.refused("clipped", "the spot touches the image's border")
    if surface == "plane":
        points = unproject_pixels_to_plane(setup.camera, spot.contour_px)
        normal = np.array([0.0, 0.0, 1.0])
    else:
        points = unproject_pixels_to_sphere(setup.camera, spot.contour_px, setup.eye.radius_mm)
        if not np.isfinite(points).all():
            return ConeCandidates.refused("clipped", "the spot runs past the retina's edge")
        normal = sphere_normal(points, setup.eye.center_in_eye)
    return apex_candidates(points, normal, setup.instrument.beam_half_angle, setup.instrument.height_correction)


def _closest_set(candidates: list[ConeCandidates]) -> tuple[int, ...]:
    """One candidate per contour: the combination whose apexes have the smallest summed pairwise distance."""
    best_spread: float | np.floating[Any]  # np.inf, then a sum of norms
    best, best_spread = (0,) * len(candidates), np.inf
    for choice in itertools.product((0, 1), repeat=len(candidates)):
        apexes = [c.apexes[i] for c, i in zip(candidates, choice, strict=True)]
        spread = sum(np.linalg.norm(p - q) for p, q in itertools.combinations(apexes, 2))
        if spread < best_spread:
            best, best_spread = choice, spread
    return best


@dataclass(frozen=True)
class ThesisSolution:
    """The thesis's reconstruction of one frame: its estimate, and the spots and candidates it chose from.

    Attributes
    ----------
    estimate : PoseEstimate
    spots : tuple of Spot
        The whole spots used.
    candidates : tuple of ConeCandidates
        Each spot's two apex candidates.
    chosen : tuple of int
        The candidate chosen for each spot.
    """

    estimate: PoseEstimate
    spots: tuple[Spot, ...] = ()
    candidates: tuple[ConeCandidates, ...] = ()
    chosen: tuple[int, ...] = ()


def solve_thesis(detection: SpotDetection, setup: Setup, surface: str = "sphere") -> ThesisSolution:
    """The thesis's reconstruction from detected spots, with what it chose (see :func:`locate_from_spots`)."""
    beams = setup.instrument.beam_count
    spots = detection.spots
    if not spots:
        return ThesisSolution(
            PoseEstimate(
                "no_spot", detail=f"no region brighter than the background (contrast {detection.contrast:.1f})"
            )
        )
    if len(spots) > beams:
        return ThesisSolution(
            PoseEstimate("ambiguous", spots=len(spots), detail=f"{len(spots)} spots, expected {beams}")
        )
    pairs = [(spot, c) for spot, c in ((spot, spot_candidates(spot, setup, surface)) for spot in spots) if c.ok]
    needed = 1 if beams == 1 else 2
    if len(pairs) < needed:
        if len(pairs) < len(spots):
            detail = "a spot reaches the image border or the retina's edge"
            return ThesisSolution(PoseEstimate("clipped", spots=len(spots), detail=detail))
        detail = f"{len(spots)} of {beams} spots, need {needed}"
        return ThesisSolution(PoseEstimate("too_few_spots", spots=len(spots), detail=detail))
    usable = [c for _, c in pairs]
    if beams == 1:
        chosen: tuple[int, ...] = (choose_by_insertion(usable[0], setup.instrument.insertion_in_eye)[0],)
        tip = usable[0].apexes[chosen[0]]
    else:
        chosen = _closest_set(usable)
        apexes = np.array([c.apexes[i] for c, i in zip(usable, chosen, strict=True)])
        tip = np.median(apexes, axis=0)  # Algorithm 2; the median of two is their mean
    if not setup.contains_point(tip):
        estimate = PoseEstimate("unreliable", spots=len(usable), detail="the fitted apex lies outside the eye")
    else:
        axis = normalize(tip - setup.instrument.insertion_in_eye)  # the thesis's axis
        detail = f"{len(usable)} of {beams} spots" if len(usable) < beams else ""
        estimate = PoseEstimate("ok", tip_in_eye=tip, axis=axis, spots=len(usable), detail=detail)
    return ThesisSolution(estimate, tuple(s for s, _ in pairs), tuple(usable), chosen)


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
    return solve_thesis(detection, setup, surface).estimate


@dataclass(frozen=True)
class HeightFactor:
    """Section 5.5's factor from one frame (:func:`fit_height_correction`), or why the frame gives none.

    Attributes
    ----------
    status : str
        ``ok``, or a :data:`~spotnav.pose.estimate.STATUSES` status: ``wrong_size``, ``ambiguous`` (more spots than
        beams), ``no_spot`` or ``clipped`` (no whole spot).
    detail : str
        The reason, for a status other than ``ok``.
    factor : float
        The factor (NaN unless ``ok``).
    """

    status: str
    detail: str = ""
    factor: float = float("nan")

    @property
    def ok(self) -> bool:
        """Whether the frame gave a factor."""
        return self.status == "ok"


def fit_height_correction(image: np.ndarray, setup: Setup, tip_in_eye: np.ndarray) -> HeightFactor:
    """Section 5.5's factor from one frame with the tip at a known position.

    The known height of the tip above each spot's fitting plane divided by the
    reconstructed height ``s2``, averaged over the visible spots; or why the
    frame shows no usable spot.
    """
    wrong = check_image_size(image, setup)
    if wrong is not None:
        return HeightFactor(wrong.status, wrong.detail)
    detection = detect_spots_otsu(image, response=setup.camera.pixel_response)
    if len(detection.spots) > setup.instrument.beam_count:
        return HeightFactor("ambiguous", f"the calibration frame shows {len(detection.spots)} spots")
    plain = replace(setup, instrument=replace(setup.instrument, height_correction=1.0))
    fits = [c for c in (spot_candidates(s, plain) for s in detection.spots) if c.ok]
    if not fits:
        return HeightFactor("clipped" if detection.spots else "no_spot", "the calibration frame shows no whole spot")
    tip_in_eye = np.asarray(tip_in_eye, dtype=float)
    factors = [float((tip_in_eye - c.plane_origin_in_eye) @ c.plane_normal_in_eye) / c.s2 for c in fits]
    return HeightFactor("ok", factor=float(np.mean(factors)))
