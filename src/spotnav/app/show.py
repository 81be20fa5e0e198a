"""``spotnav show``: one frame localized and drawn (:mod:`spotnav.app.overlay`), whole or cropped around its spots.

A refused frame shows what its method had when it refused. The precise methods keep no edge points before their fit,
so :func:`spots_before_refusal` runs their find and read stages again, as they ran (the same functions, the same
frame): the spots' sub-pixel edges where the refusal came after the light was read (``blurred``, ``unreliable``),
else the outlines of the spots found; the picture says which, or that there was none.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from spotnav.app.overlay import View, crop_box, draw_overlay
from spotnav.pose.localize import DEFAULT_METHOD, Localization, SpotDetail, localize_detailed
from spotnav.pose.pipeline import read_spot_edge
from spotnav.pose.precise import detect_spots, keep_beam_spots, plan_spots
from spotnav.setup.config import Setup

__all__ = ["Shown", "show_frame", "spots_before_refusal"]

_NOTHING_FOUND = "no edge points: no spot found"
_OUTLINES = "orange: the spots' outlines, not read"
_EDGES_READ = "orange: the edges read, not fitted"
_NOTHING_TO_CROP = "nothing to crop around"


@dataclass(frozen=True)
class Shown:
    """One frame as ``spotnav show`` draws it.

    Attributes
    ----------
    canvas : ndarray, shape (h, w, 3), uint8
        The picture, RGB.
    localization : Localization
        The method's answer and what it came from.
    spots : tuple of SpotDetail
        The edge points drawn: the localization's, or what a refused frame's method had (:func:`spots_before_refusal`).
    view : View
        The part of the frame drawn, and its zoom.
    note : str
        The line drawn under the status (what a refused frame's points are), or empty.
    """

    canvas: np.ndarray
    localization: Localization
    spots: tuple[SpotDetail, ...]
    view: View
    note: str

    def text(self) -> str:
        """What ``spotnav show`` prints: the answer, the note, and each spot's edge points and fit."""
        estimate = self.localization.estimate
        if estimate.tip_in_eye is not None:
            tip = " ".join(f"{v:.4f}" for v in estimate.tip_in_eye)
            sigma = f", sigma {estimate.sigma_mm:.4f} mm" if np.isfinite(estimate.sigma_mm) else ""  # thesis: none
            lines = [f"ok: tip {tip} mm{sigma}"]
        else:
            lines = [f"{estimate.status}: {estimate.detail}"]
        lines += [self.note] if self.note else []
        for spot in self.spots:
            line = f"beam {spot.beam}: {len(spot.edge_px)} edge points"
            if len(spot.fitted_px):
                rms = float(np.sqrt(np.mean(spot.residuals_deg**2)))
                line += f", {int(spot.inliers.sum())} of {len(spot.fitted_px)} fitted points kept, RMS {rms:.4f} deg"
            lines.append(line)
        return "\n".join(lines)


def _no_fit(beam: int, edge_px: np.ndarray) -> SpotDetail:
    return SpotDetail(beam, edge_px, np.zeros((0, 2)), np.zeros(0, dtype=bool), np.zeros(0))


def spots_before_refusal(
    image: np.ndarray, setup: Setup, localization: Localization, method: str = DEFAULT_METHOD
) -> tuple[tuple[SpotDetail, ...], str]:
    """The edge points to draw on a frame, and a note on what they are.

    The localization's own spots when it has any (every ``ok`` frame, a refused fit, the thesis method's contours).
    A precise method's frame refused before its fit has none: its find stage is run again
    (:func:`spotnav.pose.precise.detect_spots`, :func:`spotnav.pose.precise.plan_spots`) and, where it planned the
    spots' rays, their edges read (:func:`spotnav.pose.pipeline.read_spot_edge`, not judged).

    Parameters
    ----------
    image : ndarray
        The frame the localization came from.
    setup : Setup
    localization : Localization
    method : str
        The method that made it (:data:`spotnav.pose.localize.METHODS`).

    Returns
    -------
    tuple of (tuple of SpotDetail, str)
        The spots (all points not fitted, beyond the localization's own) and the note (empty for the localization's
        own spots).
    """
    estimate = localization.estimate
    if localization.spots or estimate.ok or method == "thesis" or estimate.status == "wrong_size":
        return localization.spots, ""
    detection = detect_spots(image, setup)
    if not detection.spots:
        return (), _NOTHING_FOUND
    outlines = tuple(_no_fit(number, spot.contour_px) for number, spot in enumerate(detection.spots))
    kept, ambiguous = keep_beam_spots(detection, setup)  # as the method does
    if ambiguous:  # refused on the count, before any plan
        return outlines, _OUTLINES
    planned = plan_spots(kept, setup, through_insertion=method == "precise")
    if planned.plan is None:
        return outlines, _OUTLINES
    plan = planned.plan
    edges = tuple(
        _no_fit(beam, read_spot_edge(image, setup, plan, spot).pixels) for spot, beam in enumerate(plan.beams)
    )
    return edges, _EDGES_READ


def show_frame(image: np.ndarray, setup: Setup, method: str = DEFAULT_METHOD, *, crop: bool = False) -> Shown:
    """Localize one frame and draw it: its edge points, the fitted cones above them, the tip and the status.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3), uint8 or uint16
        The frame, the camera's size.
    setup : Setup
    method : str
        One of :data:`spotnav.pose.localize.METHODS`.
    crop : bool
        Draw only the part around the spots, cones and tip (:func:`spotnav.app.overlay.crop_box`), enlarged
        (:meth:`spotnav.app.overlay.View.enlarged`); a refused frame's around what its method had found.

    Returns
    -------
    Shown
    """
    localization = localize_detailed(image, setup, method)
    spots, note = spots_before_refusal(image, setup, localization, method)
    view = View.whole(image)
    if crop and (any(len(spot.edge_px) for spot in spots) or localization.cones or localization.estimate.ok):
        box = crop_box(setup, replace(localization, spots=spots))
        view = View.enlarged(box, (setup.camera.width_px, setup.camera.height_px))
    elif crop:
        note = "; ".join(filter(None, [note, _NOTHING_TO_CROP]))
    estimate = localization.estimate
    canvas = draw_overlay(image, setup, estimate, spots=spots, cones=localization.cones, view=view, note=note)
    return Shown(canvas, localization, spots, view, note)
