"""Shaft occlusion: the edge points that the instrument's shaft hides from the camera, and the ones it leaves."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from spotnav.optics.camera import unproject_pixels_to_sphere
from spotnav.optics.occlusion import pixels_behind_segment
from spotnav.pose.checks import MIN_EDGE_POINTS
from spotnav.setup.config import Setup

__all__ = ["VisibleEdges", "hidden_by_shaft", "visible_edge_points"]

_MAX_HIDDEN_FRACTION = 0.6  # a spot whose edge the shaft hides more than this is occluded


@dataclass(frozen=True)
class VisibleEdges:
    """The edge points the shaft leaves visible (:func:`visible_edge_points`).

    Attributes
    ----------
    status : str
        ``ok``, or ``occluded`` (a :data:`~spotnav.pose.estimate.STATUSES` status).
    detail : str
        The reason, for ``occluded``.
    edges_px : tuple of ndarray, shape (N_k, 2)
        Each spot's visible edge points, pixels (empty unless ``ok``).
    """

    status: str
    detail: str = ""
    edges_px: tuple[np.ndarray, ...] = ()

    @property
    def ok(self) -> bool:
        """Whether every spot keeps enough of its edge."""
        return self.status == "ok"


def hidden_by_shaft(
    setup: Setup,
    edges_px: Sequence[np.ndarray],
    tip_in_eye: np.ndarray,
    axis: np.ndarray,
    margin_mm: float = 0.05,
) -> list[np.ndarray]:
    """Which edge points the instrument's shaft hides from the camera, for a pose.

    The shaft (``instrument.shaft_diameter_mm``) runs from the tip back along
    the axis as far as the insertion point; points within ``margin_mm`` of
    its outline count as hidden too (the edge detector's rays that graze the
    shaft, and the pose's own error).

    Parameters
    ----------
    edges_px : sequence of ndarray, shape (N_k, 2)
        Each spot's edge points, pixels.
    tip_in_eye, axis : ndarray, shape (3,)
    margin_mm : float

    Returns
    -------
    list of ndarray of bool, shape (N_k,)
    """
    instrument = setup.instrument
    if instrument.shaft_diameter_mm == 0:
        return [np.zeros(len(edge), dtype=bool) for edge in edges_px]
    offset = instrument.insertion_in_eye - tip_in_eye  # its length as np.linalg.norm's, without its checks
    end = tip_in_eye - axis * float(np.sqrt(offset.dot(offset)))
    radius = instrument.shaft_diameter_mm / 2.0 + margin_mm
    return [pixels_behind_segment(setup.camera, edge, tip_in_eye, end, radius) for edge in edges_px]


def visible_edge_points(setup: Setup, edges_px: Sequence[np.ndarray], hidden: Sequence[np.ndarray]) -> VisibleEdges:
    """Each spot's edge points (pixels) that are not hidden and lie on the retina, or ``occluded``.

    ``occluded`` when the shaft hides over 60 % of a spot's edge or leaves
    fewer than :data:`~spotnav.pose.checks.MIN_EDGE_POINTS` of it.
    """
    visible = []
    for edge, covered in zip(edges_px, hidden, strict=True):
        count = int(np.count_nonzero(covered))
        if count > _MAX_HIDDEN_FRACTION * len(covered) or len(covered) - count < MIN_EDGE_POINTS:
            detail = f"the shaft hides {100 * count / max(len(covered), 1):.0f} % of a spot's edge"
            return VisibleEdges("occluded", detail)
        shown = edge[~covered] if count else edge
        on_sphere = unproject_pixels_to_sphere(setup.camera, shown, setup.eye.radius_mm)
        visible.append(shown[np.isfinite(on_sphere).all(axis=1)])
    return VisibleEdges("ok", edges_px=tuple(visible))
