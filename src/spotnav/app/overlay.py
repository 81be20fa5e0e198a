"""Draw what a method saw and fitted over its frame: edge points, the fitted cones' edges, the tip, the status.

Colours: fitted edge points the robust fit kept in green, those it left out in
red, edge points the fit did not use (hidden by the shaft; the thesis's
contour) in orange; each fitted cone's edge on the retina, projected, in cyan;
the tip's projection as a yellow cross; the status in the top-left corner.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from spotnav.optics.camera import project_points
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.localize import Cone, Localization, SpotDetail, cones_of_estimate
from spotnav.setup.config import Setup
from spotnav.setup.geometry import cone_sphere_curve

__all__ = ["cone_edge_px", "crop_box", "draw_overlay", "fitted_spots"]

_GREEN, _RED, _ORANGE = (0, 220, 0), (255, 40, 40), (255, 150, 0)
_CYAN, _YELLOW, _WHITE = (0, 230, 255), (255, 255, 0), (255, 255, 255)
_CURVE_POINTS = 180


def _rgb8(image: np.ndarray) -> np.ndarray:
    """The frame as 8-bit RGB (16-bit values scaled down, grey repeated, alpha dropped), a copy."""
    pixels = np.asarray(image)
    if pixels.dtype == np.uint16:
        pixels = (pixels >> 8).astype(np.uint8)
    if pixels.ndim == 2:
        return np.repeat(pixels[:, :, None], 3, axis=2)
    return pixels[:, :, :3].copy()


def cone_edge_px(setup: Setup, cone: Cone) -> np.ndarray:
    """The cone's edge on the retina, projected into the image, shape (K, 2) px (empty if it misses)."""
    if np.linalg.norm(np.asarray(cone.apex_in_eye, float) - setup.eye.center_in_eye) >= setup.eye.radius_mm:
        return np.zeros((0, 2))  # the apex lies outside the eye: cone_sphere_curve draws no curve for it
    curve = cone_sphere_curve(
        cone.apex_in_eye,
        cone.axis_in_eye,
        np.radians(cone.half_angle_deg),
        setup.eye.center_in_eye,
        setup.eye.radius_mm,
        _CURVE_POINTS,
    )
    pixels = project_points(setup.camera, curve)
    return pixels[np.all(np.isfinite(pixels), axis=1)]


def fitted_spots(edges_px: Sequence[np.ndarray]) -> tuple[SpotDetail, ...]:
    """Spots from the edge points a fit used, per beam (a tracked frame's): all fitted, residuals unknown."""
    return tuple(
        SpotDetail(beam, edge, edge, np.ones(len(edge), dtype=bool), np.full(len(edge), np.nan))
        for beam, edge in enumerate(edges_px)
    )


def _status_text(estimate: PoseEstimate, label: str) -> str:
    if estimate.ok:
        text = f"ok, sigma {estimate.sigma_mm:.4f} mm" if np.isfinite(estimate.sigma_mm) else "ok"
    else:
        text = f"{estimate.status}: {estimate.detail}" if estimate.detail else estimate.status
    return f"{label}: {text}" if label else text


def draw_overlay(
    image: np.ndarray,
    setup: Setup,
    estimate: PoseEstimate,
    *,
    spots: Sequence[SpotDetail] = (),
    cones: Sequence[Cone] | None = None,
    label: str = "",
) -> np.ndarray:
    """The frame with the edge points, the cones' projected edges, the tip and the status drawn on it.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3|4), uint8 or uint16
    setup : Setup
    estimate : PoseEstimate
    spots : sequence of SpotDetail
        Edge points to draw (:class:`~spotnav.pose.localize.Localization`'s ``spots``).
    cones : sequence of Cone, optional
        The cones to draw; default: the estimate's (none without a pose).
    label : str
        Put before the status (a frame number, a tracking mode).

    Returns
    -------
    ndarray, shape (H, W, 3), uint8
        RGB.
    """
    canvas = _rgb8(image)
    size = max(canvas.shape[:2])
    thick = max(1, round(size / 1500))
    for cone in cones_of_estimate(setup, estimate) if cones is None else cones:
        curve = cone_edge_px(setup, cone)
        if len(curve) > 1:
            cv2.polylines(canvas, [np.round(curve).astype(np.int32)], True, _CYAN, thick)
    for spot in spots:
        fitted = {tuple(np.round(p, 3)) for p in spot.fitted_px}
        for point in spot.edge_px:
            if tuple(np.round(point, 3)) not in fitted:
                cv2.circle(canvas, tuple(np.round(point).astype(int)), thick, _ORANGE, -1)
        for point, kept in zip(spot.fitted_px, spot.inliers, strict=True):
            cv2.circle(canvas, tuple(np.round(point).astype(int)), thick, _GREEN if kept else _RED, -1)
    if estimate.tip_in_eye is not None:
        tip = project_points(setup.camera, estimate.tip_in_eye)
        if np.all(np.isfinite(tip)):
            cv2.drawMarker(canvas, tuple(np.round(tip).astype(int)), _YELLOW, cv2.MARKER_CROSS, 12 * thick, thick)
    scale = max(0.5, size / 2000)
    cv2.putText(canvas, _status_text(estimate, label), (10, round(30 * scale)), cv2.FONT_HERSHEY_SIMPLEX, scale, _WHITE,
                thick, cv2.LINE_AA)  # fmt: skip
    return canvas


def crop_box(setup: Setup, localization: Localization, margin: float = 0.3) -> tuple[int, int, int, int]:
    """The part of the frame around the spots and the cones' edges: ``(x0, y0, x1, y1)`` px, ``margin`` of its size.

    The whole frame when there is nothing to frame.
    """
    points = [spot.edge_px for spot in localization.spots]
    points += [cone_edge_px(setup, cone) for cone in localization.cones]
    points = [p for p in points if len(p)]
    width, height = setup.camera.width_px, setup.camera.height_px
    if not points:
        return 0, 0, width, height
    every = np.concatenate(points)
    low, high = every.min(axis=0), every.max(axis=0)
    pad = margin * float(np.max(high - low)) + 10
    x0, y0 = np.maximum(np.floor(low - pad), 0).astype(int)
    x1, y1 = np.minimum(np.ceil(high + pad), [width, height]).astype(int)
    return int(x0), int(y0), int(x1), int(y1)
