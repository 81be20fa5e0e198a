"""Bright regions grouped into spots: the fragments of a spot that dark vessels cut lie on one ellipse together
(:func:`group_fragments`), and a spot's outer boundary is the convex part of its contour, which no occluder carved
(:func:`outer_boundary`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import cv2
import numpy as np
from numba import njit

from spotnav.image.spots import _MIN_AREA_FRACTION, _MIN_CONTOUR_POINTS, Spot, SpotDetection

__all__ = ["group_fragments", "outer_boundary"]


_HULL_TOLERANCE_PX = 1.5  # a contour point this close to the convex hull is on the outer boundary
_GROUP_RMS_PX = 1.5  # fragments whose outer boundaries an ellipse fits this well (or ...
_GROUP_RMS_FRACTION = 0.03  # ... to this fraction of its radius) are one spot
_MAX_FRAGMENTS = 32  # the largest regions grouped: 12 vessels cut a spot into some 20
_SUSPECTS = 3  # a group that does not fit tries leaving out this many of its worst-fitting regions


def _near_hull(points_px: np.ndarray, tolerance_px: float) -> np.ndarray:
    """Which of ``points_px`` (N, 2) lie within ``tolerance_px`` of their convex hull's boundary (N,)."""
    hull = cv2.convexHull(points_px.astype(np.float32)).reshape(-1, 2).astype(float)
    if len(hull) < 3:
        return np.ones(len(points_px), dtype=bool)
    return _near_sides(np.asarray(points_px, dtype=float), hull, tolerance_px)


@njit(cache=True)
def _near_sides(points_px: np.ndarray, hull: np.ndarray, tolerance_px: float) -> np.ndarray:
    """Which of ``points_px`` (N, 2), inside the convex polygon ``hull`` (H, 2), lie within ``tolerance_px`` of a
    side's line: the distance to the boundary of a point inside is the least to a side's line.

    Each point's search starts at the side the last point found near was near: along a contour, usually its own.
    """
    count = len(hull)
    sides, lengths = np.empty((count, 2)), np.empty(count)
    for h in range(count):
        sides[h, 0], sides[h, 1] = hull[(h + 1) % count, 0] - hull[h, 0], hull[(h + 1) % count, 1] - hull[h, 1]
        lengths[h] = max(np.hypot(sides[h, 0], sides[h, 1]), 1e-9)
    near = np.zeros(len(points_px), dtype=np.bool_)
    last = 0
    for n in range(len(points_px)):
        for k in range(count):
            h = (last + k) % count
            offset_u, offset_v = points_px[n, 0] - hull[h, 0], points_px[n, 1] - hull[h, 1]
            if abs(sides[h, 0] * offset_v - sides[h, 1] * offset_u) / lengths[h] <= tolerance_px:
                near[n], last = True, h
                break
    return near


def _ellipse_distances(points_px: np.ndarray, ellipse: cv2.typing.RotatedRect) -> np.ndarray:
    """Approximate distances (N,) of ``points_px`` (N, 2) from an ellipse as ``cv2.fitEllipse`` gives it, pixels.

    Along the ray from the ellipse's centre: ``(rho - 1) r / rho`` with ``rho``
    the point's normalised radius and ``r`` its distance from the centre.
    """
    (cu, cv), (width, height), angle = ellipse
    cos, sin = np.cos(np.radians(angle)), np.sin(np.radians(angle))
    du, dv = points_px[:, 0] - cu, points_px[:, 1] - cv
    x, y = cos * du + sin * dv, -sin * du + cos * dv
    rho = np.hypot(x / max(width / 2.0, 1e-9), y / max(height / 2.0, 1e-9))
    distances: np.ndarray = (rho - 1.0) * np.hypot(x, y) / np.maximum(rho, 1e-9)
    return distances


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2))) if len(values) else 0.0


_GROUP_KERNEL_PX = 8  # group_fragments grows regions on a grid where half the gap is at most about this


def group_fragments(
    detection: SpotDetection, shape: tuple[int, int], gap_px: float, whole_area_px: float
) -> SpotDetection:
    """Bright regions grouped into spots: regions whose outer boundaries lie on one ellipse together are one spot.

    A cone's spot is convex and close to an ellipse; dark vessels across it
    cut it into fragments whose outer boundaries still lie on that ellipse,
    while the boundaries of two spots (or of a spot and a glint beside it) do
    not. Regions less than ``gap_px`` apart (a vessel's width) are one
    cluster. A cluster is one spot when the ellipse fitted to its contour
    points near its convex hull fits them within ``_GROUP_RMS_PX`` or
    ``_GROUP_RMS_FRACTION`` of its mean radius (RMS), and at most one of its
    regions is a whole spot by itself (:func:`_is_whole`); otherwise the region
    whose removal fits best leaves it, until the rest fits, and the regions
    that left are grouped alike. A grouped spot's contour is those points,
    its area its convex hull's.

    Parameters
    ----------
    detection : SpotDetection
        Regions found with a small ``min_area_fraction`` (the fragments).
    shape : tuple of int
        The image's ``(height, width)``.
    gap_px : float
        The widest gap between two fragments of one spot, pixels.
    whole_area_px : float
        The smallest area a whole spot may have, pixels: a region this large
        that an ellipse fits is a spot, never a fragment of one.

    Returns
    -------
    SpotDetection
        Spots largest first (made of the ``_MAX_FRAGMENTS`` largest regions;
        those under ``_MIN_AREA_FRACTION`` of the largest dropped as clutter),
        with ``fragments`` the regions found.
    """
    regions = detection.spots[:_MAX_FRAGMENTS]  # largest first: the rest (noise, dust) is clutter
    if len(regions) < 2:
        return replace(detection, fragments=len(detection.spots))
    # Regions closer than the gap touch once each grows by half of it: on a grid coarse enough that the
    # growing kernel stays under _GROUP_KERNEL_PX (a 70 px kernel over a 5000 px frame took 1.8 s).
    reach_px = max(gap_px / 2.0, 1.0)
    scale = max(1, int(reach_px // _GROUP_KERNEL_PX))
    labels = np.zeros((-(-shape[0] // scale), -(-shape[1] // scale)), dtype=np.uint8)
    for region in regions:
        cv2.fillPoly(labels, [np.round((region.contour_px + 0.5) / scale - 0.5).astype(np.int32)], 255)
    reach = max(int(np.ceil(reach_px / scale)), 1)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1, 2 * reach + 1))
    _, clusters = cv2.connectedComponents(cv2.dilate(labels, kernel))
    first = [np.round((r.contour_px[0] + 0.5) / scale - 0.5).astype(int) for r in regions]
    cluster_of = [int(clusters[min(v, labels.shape[0] - 1), min(u, labels.shape[1] - 1)]) for u, v in first]
    spots: list[Spot] = []
    for cluster in sorted(set(cluster_of)):
        members = [r for r, c in zip(regions, cluster_of, strict=True) if c == cluster]
        while members:
            group, members = _ellipse_group(members, whole_area_px)
            spots.append(group[0] if len(group) == 1 else _merged(group))
    spots.sort(key=lambda spot: -spot.area_px)
    kept = tuple(spot for spot in spots if spot.area_px >= _MIN_AREA_FRACTION * spots[0].area_px)
    return replace(detection, spots=kept, fragments=len(detection.spots))


def _is_whole(region: Spot, whole_area_px: float) -> bool:
    """Whether a region is a whole spot by itself: at least ``whole_area_px`` large, and an ellipse fits its
    whole contour (not only its outer points) within ``_GROUP_RMS_FRACTION`` of its radius, or a pixel."""
    if region.area_px < whole_area_px or len(region.contour_px) < _MIN_CONTOUR_POINTS:
        return False
    ellipse = cv2.fitEllipseDirect(region.contour_px.astype(np.float32))
    tolerance = max(1.0, _GROUP_RMS_FRACTION * 0.25 * (ellipse[1][0] + ellipse[1][1]))
    return _rms(_ellipse_distances(region.contour_px.astype(float), ellipse)) <= tolerance


def _ellipse_group(members: list[Spot], whole_area_px: float) -> tuple[list[Spot], list[Spot]]:
    """The regions of ``members`` that make one spot (see :func:`group_fragments`), and the others."""
    group, others = list(members), []
    whole = [_is_whole(region, whole_area_px) for region in group]
    while len(group) > 1:
        errors = _ellipse_errors(group)
        if errors.max() <= 1.0 and sum(whole) <= 1:
            break
        # Of the regions that fit worst (and the whole spots, when there are two), the one whose removal fits best.
        suspects = set(np.argsort(-errors)[:_SUSPECTS].tolist()) | (
            {i for i, w in enumerate(whole) if w} if sum(whole) > 1 else set()
        )
        worst = min(suspects, key=lambda i: _ellipse_errors(group[:i] + group[i + 1 :]).max())
        others.append(group.pop(worst))
        whole.pop(worst)
    return group, others


def _outer_points(group: Sequence[Spot]) -> tuple[np.ndarray, np.ndarray]:
    """The group's contour points near its convex hull, and which region (index in ``group``) each came from."""
    points = np.concatenate([spot.contour_px for spot in group]).astype(float)
    owner = np.concatenate([np.full(len(spot.contour_px), i) for i, spot in enumerate(group)])
    near = _near_hull(points, _HULL_TOLERANCE_PX)
    return points[near], owner[near]


def _ellipse_errors(group: Sequence[Spot]) -> np.ndarray:
    """How far each region's outer points lie from the ellipse the group's fit, RMS over the tolerance (len(group),).

    The tolerance is ``_GROUP_RMS_PX`` or ``_GROUP_RMS_FRACTION`` of the
    ellipse's mean radius; a region with no outer point scores 0.
    """
    points, owner = _outer_points(group)
    if len(points) < _MIN_CONTOUR_POINTS:
        return np.full(len(group), np.inf)
    ellipse = cv2.fitEllipseDirect(points.astype(np.float32))
    tolerance = max(_GROUP_RMS_PX, _GROUP_RMS_FRACTION * 0.25 * (ellipse[1][0] + ellipse[1][1]))
    distances = _ellipse_distances(points, ellipse)
    return np.array([_rms(distances[owner == i]) for i in range(len(group))]) / tolerance


def _merged(group: Sequence[Spot]) -> Spot:
    """One spot from the fragments of ``group``: their outer boundary (in order around it), their hull's area."""
    points, _ = _outer_points(group)
    offsets = points - points.mean(axis=0)
    points = points[np.argsort(np.arctan2(offsets[:, 1], offsets[:, 0]))]  # in order around the spot
    hull = cv2.convexHull(points.astype(np.float32))
    return Spot(points, float(cv2.contourArea(hull)), any(spot.touches_border for spot in group))


def outer_boundary(spot: Spot, tolerance_px: float = _HULL_TOLERANCE_PX) -> Spot:
    """The spot with only the convex part of its contour: the boundary that no occluder carved.

    A cone's spot is convex; where something opaque in front of it (the
    instrument's shaft, a dark vessel) cuts into it, its contour turns inward.
    The contour points within ``tolerance_px`` of the contour's convex hull
    are kept (all of them for a convex spot), in order.

    Parameters
    ----------
    spot : Spot
    tolerance_px : float

    Returns
    -------
    Spot
        With ``contour_px`` reduced (at least 5 points, else the spot unchanged).
    """
    outer = spot.contour_px[_near_hull(spot.contour_px.astype(float), tolerance_px)]
    if len(outer) < _MIN_CONTOUR_POINTS:
        return spot
    return replace(spot, contour_px=outer)
