"""Draw what a method saw and fitted over its frame: edge points, the fitted cones' edges, the tip, the status.

Colours: fitted edge points the robust fit kept in green, those it left out in
red, edge points the fit did not use (hidden by the shaft; the thesis's
contour; a refused frame's edges or spot outlines) in orange, as dots; above
them, each fitted cone's edge on the retina, projected, as a thinner cyan line
(a point on it shows on both sides); the tip's projection as a yellow cross; the status (and its
detail) in white on a dark box in the top-left corner, after a square of the
status's colour (:mod:`spotnav.app.status_style`). A :class:`View` draws a part
of the frame, enlarged, in the same way.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from spotnav.app.status_style import status_style
from spotnav.optics.camera import project_points
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.localize import Cone, Localization, SpotDetail, cones_of_estimate
from spotnav.setup.config import Setup
from spotnav.setup.geometry import cone_sphere_curve

__all__ = ["View", "box_around", "cone_edge_px", "crop_box", "draw_overlay", "fitted_spots"]

_GREEN, _RED, _ORANGE = (0, 220, 0), (255, 40, 40), (255, 150, 0)
_CYAN, _YELLOW, _WHITE = (0, 230, 255), (255, 255, 0), (255, 255, 255)
_CURVE_POINTS = 180
_TEXT_BOX_OPACITY = 0.7
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_ZOOMED_PX = 800  # a crop is enlarged toward this size (its longer side), by a whole factor
_SMALLEST_CROP_PX = 240  # room for the status text
_TEXT_SHARE = 3  # the text takes at most a third of the picture's height: a long detail is cut short (...)


@dataclass(frozen=True)
class View:
    """The part of a frame an overlay shows, and how much it enlarges it.

    Attributes
    ----------
    box : tuple of int
        ``(x0, y0, x1, y1)``: the columns ``x0 <= u < x1`` and rows ``y0 <= v < y1`` shown, pixels.
    zoom : int
        Each frame pixel becomes ``zoom`` by ``zoom`` canvas pixels.
    """

    box: tuple[int, int, int, int]
    zoom: int = 1

    @classmethod
    def whole(cls, image: np.ndarray) -> View:
        """The whole frame, not enlarged."""
        height, width = np.asarray(image).shape[:2]
        return cls((0, 0, int(width), int(height)))

    @classmethod
    def enlarged(cls, box: tuple[int, int, int, int], frame_size: tuple[int, int]) -> View:
        """``box`` enlarged by the largest whole factor that keeps its longer side within ``_ZOOMED_PX`` and within
        half the frame's longer side (``frame_size``: width, height, pixels): a crop stays smaller than its frame."""
        x0, y0, x1, y1 = box
        longest = max(x1 - x0, y1 - y0, 1)
        return cls(box, max(1, min(_ZOOMED_PX, max(frame_size) // 2) // longest))

    def to_canvas(self, points_px: np.ndarray) -> np.ndarray:
        """Frame pixels ``(u, v)``, shape (..., 2), to the canvas's pixels (pixel centres at integers)."""
        offset = np.array(self.box[:2], dtype=float)
        points: np.ndarray = np.asarray(points_px, dtype=float) - offset
        return points * self.zoom + (self.zoom - 1) / 2

    def cut(self, canvas: np.ndarray) -> np.ndarray:
        """The box's pixels of an RGB frame, each repeated ``zoom`` times across and down."""
        x0, y0, x1, y1 = self.box
        part = canvas[y0:y1, x0:x1]
        return np.ascontiguousarray(np.repeat(np.repeat(part, self.zoom, axis=0), self.zoom, axis=1))


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


def _wrapped(text: str, width_px: int, scale: float, thick: int) -> list[str]:
    """``text`` broken between words into lines no wider than ``width_px`` (a longer word stands alone)."""
    lines: list[str] = []
    for word in text.split():
        joined = f"{lines[-1]} {word}" if lines else word
        if lines and cv2.getTextSize(joined, _FONT, scale, thick)[0][0] <= width_px:
            lines[-1] = joined
        else:
            lines.append(word)
    return lines


def _fitted_lines(texts: Sequence[str], most: int, width_px: int, scale: float, thick: int) -> list[str]:
    """Each text wrapped (:func:`_wrapped`), all in at most ``most`` lines (at least one each); a text cut short
    ends with ``...``."""
    lines: list[str] = []
    for number, text in enumerate(texts):
        wrapped = _wrapped(text, width_px, scale, thick)
        room = max(1, most - len(lines) - (len(texts) - number - 1))
        if len(wrapped) > room:
            last = wrapped[room - 1].split()
            while len(last) > 1 and cv2.getTextSize(" ".join(last) + " ...", _FONT, scale, thick)[0][0] > width_px:
                last.pop()
            wrapped = [*wrapped[: room - 1], " ".join(last) + " ..."]
        lines += wrapped
    return lines


def _draw_status(canvas: np.ndarray, texts: Sequence[str], colour: tuple[int, int, int], thick: int) -> None:
    """The texts, wrapped, white on a dark box in the top-left corner, after a square of ``colour``; in place."""
    height, width = canvas.shape[:2]
    scale = max(0.4, max(height, width) / 2000)
    (_, text_height), _ = cv2.getTextSize("Ag", _FONT, scale, thick)
    step, pad = round(1.6 * text_height), round(0.5 * text_height)
    swatch = step
    most = height // _TEXT_SHARE // step
    lines = _fitted_lines(texts, most, width - swatch - 3 * pad, scale, thick)
    widest = max(cv2.getTextSize(line, _FONT, scale, thick)[0][0] for line in lines)
    right, bottom = min(width, swatch + widest + 3 * pad), min(height, step * len(lines) + 2 * pad)
    box = canvas[:bottom, :right]
    box[:] = np.round((1 - _TEXT_BOX_OPACITY) * box).astype(np.uint8)
    cv2.rectangle(canvas, (pad, pad), (pad + swatch - 1, pad + swatch - 1), colour, -1)
    cv2.rectangle(canvas, (pad, pad), (pad + swatch - 1, pad + swatch - 1), _WHITE, 1)  # no_spot's black shows too
    for number, line in enumerate(lines):
        baseline = pad + number * step + round(0.5 * (step + text_height))
        cv2.putText(canvas, line, (swatch + 2 * pad, baseline), _FONT, scale, _WHITE, thick, cv2.LINE_AA)


def _tip_px(setup: Setup, estimate: PoseEstimate, cones: Sequence[Cone]) -> np.ndarray | None:
    """The tip's projection, pixels: the estimate's, or a refused fit's (its cones' apex); None without either."""
    tip = estimate.tip_in_eye if estimate.tip_in_eye is not None else (cones[0].apex_in_eye if cones else None)
    if tip is None:
        return None
    pixel = project_points(setup.camera, np.asarray(tip, dtype=float))
    return pixel if np.all(np.isfinite(pixel)) else None


def draw_overlay(
    image: np.ndarray,
    setup: Setup,
    estimate: PoseEstimate,
    *,
    spots: Sequence[SpotDetail] = (),
    cones: Sequence[Cone] | None = None,
    label: str = "",
    view: View | None = None,
    note: str = "",
) -> np.ndarray:
    """The frame with the edge points, the cones' projected edges above them, the tip and the status drawn on it.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3|4), uint8 or uint16
    setup : Setup
    estimate : PoseEstimate
    spots : sequence of SpotDetail
        Edge points to draw (:class:`~spotnav.pose.localize.Localization`'s ``spots``).
    cones : sequence of Cone, optional
        The cones to draw; default: the estimate's (none without a pose). A refused fit's cones also place the
        tip's cross at their apex.
    label : str
        Put before the status (a frame number, a tracking mode).
    view : View, optional
        The part of the frame to draw, enlarged; default: the whole frame.
    note : str
        A line under the status (what a refused frame's picture shows).

    Returns
    -------
    ndarray, shape (h, w, 3), uint8
        RGB: the view's box times its zoom (the frame's size by default).
    """
    view = View.whole(image) if view is None else view
    canvas = view.cut(_rgb8(image))
    thick = max(1, round(max(canvas.shape[:2]) / 1500))
    cones = cones_of_estimate(setup, estimate) if cones is None else tuple(cones)

    line = thick if view.zoom < 2 else 2 * thick
    radius = line + view.zoom // 2  # wider than the cones' line: a point on its cone shows on both sides

    def dot(point_px: np.ndarray, colour: tuple[int, int, int]) -> None:
        cv2.circle(canvas, tuple(np.round(view.to_canvas(point_px)).astype(int)), radius, colour, -1)

    for spot in spots:
        fitted = {tuple(np.round(p, 3)) for p in spot.fitted_px}
        for point in spot.edge_px:
            if tuple(np.round(point, 3)) not in fitted:
                dot(point, _ORANGE)
        for point, kept in zip(spot.fitted_px, spot.inliers, strict=True):
            dot(point, _GREEN if kept else _RED)
    for cone in cones:  # above the points: the fit is what the points are judged against
        curve = cone_edge_px(setup, cone)
        if len(curve) > 1:
            cv2.polylines(canvas, [np.round(view.to_canvas(curve)).astype(np.int32)], True, _CYAN, line)
    tip = _tip_px(setup, estimate, cones)
    if tip is not None:
        centre = tuple(np.round(view.to_canvas(tip)).astype(int))
        cv2.drawMarker(canvas, centre, _YELLOW, cv2.MARKER_CROSS, 16 * thick, 2 * thick)
    texts = [_status_text(estimate, label), *([note] if note else [])]
    _draw_status(canvas, texts, status_style(estimate.status).rgb, thick)
    return canvas


def box_around(
    points_px: Sequence[np.ndarray], frame_size: tuple[int, int], margin: float = 0.3
) -> tuple[int, int, int, int]:
    """The part of the frame around some points: ``(x0, y0, x1, y1)`` px, ``margin`` of its size (and 10 px) on
    each side, at least ``_SMALLEST_CROP_PX`` across (moved inward at the frame's border, not cut); the whole frame
    (``frame_size``: width, height) without any point.
    """
    size = np.array(frame_size)
    chosen = [np.asarray(p, dtype=float).reshape(-1, 2) for p in points_px]
    every = np.concatenate(chosen) if chosen else np.zeros((0, 2))
    every = every[np.all(np.isfinite(every), axis=1)]
    if not len(every):
        return 0, 0, int(size[0]), int(size[1])
    low, high = every.min(axis=0), every.max(axis=0)
    pad = np.maximum(margin * float(np.max(high - low)) + 10, (_SMALLEST_CROP_PX - (high - low)) / 2)
    start, end = np.floor(low - pad), np.ceil(high + pad)
    back = np.minimum(np.maximum(end - size, 0), np.maximum(start, 0))  # past the far border: back, to the near one
    start, end = start - back, end - back
    on = np.minimum(np.maximum(-start, 0), np.maximum(size - end, 0))  # past the near border: on, to the far one
    start, end = start + on, end + on
    x0, y0 = np.maximum(start, 0).astype(int)
    x1, y1 = np.minimum(end, size).astype(int)
    return int(x0), int(y0), int(x1), int(y1)


def crop_box(setup: Setup, localization: Localization, margin: float = 0.3) -> tuple[int, int, int, int]:
    """The part of the frame around the spots' edge points, the cones' edges and an ``ok`` tip (:func:`box_around`).

    The whole frame when there is nothing to frame.
    """
    points = [spot.edge_px for spot in localization.spots]
    points += [cone_edge_px(setup, cone) for cone in localization.cones]
    tip = _tip_px(setup, localization.estimate, ())  # an ok estimate's: a refused fit's may lie anywhere
    points += [] if tip is None else [tip]
    return box_around(points, (setup.camera.width_px, setup.camera.height_px), margin)
