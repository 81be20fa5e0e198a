"""Spot detection: the thesis's (section 5.3, Algorithm 1) and spotnav's sub-pixel edges.

The thesis's: grey conversion, median blur, Gaussian blur, Otsu threshold and
``findContours`` without approximation; contours of more than 5 points.
spotnav's precise method starts from those contours and locates each spot's
edge to a fraction of a pixel along rays (:func:`detect_edge_subpixel`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

__all__ = [
    "Spot",
    "SpotDetection",
    "SpotEdge",
    "detect_edge_along_rays",
    "detect_edge_subpixel",
    "detect_spots_otsu",
    "edge_window_px",
    "linear_luminance",
    "outer_boundary",
    "rays_through_curve",
    "to_gray8",
]

_MIN_CONTOUR_POINTS = 5
_MIN_AREA_FRACTION = 0.1  # blobs smaller than this fraction of the largest are clutter
_MIN_CONTRAST_DN = 6.0


@dataclass(frozen=True)
class Spot:
    """One bright region.

    Attributes
    ----------
    contour_px : ndarray, shape (N, 2)
        Boundary pixels ``(u, v)``, as ``findContours`` returns them.
    area_px : float
        Enclosed area in pixels.
    touches_border : bool
        Whether the region reaches the image's edge (the spot is cut).
    """

    contour_px: np.ndarray
    area_px: float
    touches_border: bool


@dataclass(frozen=True)
class SpotDetection:
    """Result of spot detection.

    Attributes
    ----------
    spots : tuple of Spot
        Significant regions, largest first; empty when no spot is seen.
    threshold : float
        Otsu's threshold on the blurred 8-bit grey image.
    contrast : float
        Mean grey level of the largest region minus the background's median, in
        grey levels (0 when nothing was found).
    """

    spots: tuple[Spot, ...]
    threshold: float
    contrast: float


def to_gray8(image: np.ndarray) -> np.ndarray:
    """8-bit grey image from grey, RGB or RGBA, 8 or 16 bits.

    Parameters
    ----------
    image : ndarray, shape (H, W), (H, W, 3) or (H, W, 4), uint8 or uint16
        Colour images are RGB(A).

    Returns
    -------
    ndarray, shape (H, W), uint8

    Raises
    ------
    ValueError
        For any other shape or dtype.
    """
    if image.dtype == np.uint16:
        image = (image.astype(np.float32) * (255.0 / 65535.0) + 0.5).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise ValueError(f"image must be 8-bit or 16-bit, got {image.dtype}")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_RGBA2GRAY)
    raise ValueError(f"image must be grey, RGB or RGBA, got shape {image.shape}")


def _histogram_median(histogram: np.ndarray) -> int:
    """Median level of a histogram of integer levels (the lower one on a tie)."""
    cumulative = np.cumsum(histogram)
    return int(np.searchsorted(cumulative, 0.5 * cumulative[-1]))


def detect_spots_otsu(image: np.ndarray, blur_px: int = 5, min_contrast_sigma: float = 6.0) -> SpotDetection:
    """Find the bright spots as the thesis does.

    Parameters
    ----------
    image : ndarray
        Grey, RGB or RGBA, 8 or 16 bits (see :func:`to_gray8`).
    blur_px : int
        Odd kernel size of the median and Gaussian blurs.
    min_contrast_sigma : float
        A spot must stand out from the background's median by this many of the
        background's robust standard deviations (and by 6 grey levels).

    Returns
    -------
    SpotDetection
    """
    gray = to_gray8(image)
    blurred = cv2.GaussianBlur(cv2.medianBlur(gray, blur_px), (blur_px, blur_px), 0)
    threshold, binary = cv2.threshold(blurred, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    contours = [c.reshape(-1, 2) for c in contours if len(c) > _MIN_CONTOUR_POINTS]
    if not contours:
        return SpotDetection((), float(threshold), 0.0)
    areas = np.array([cv2.contourArea(c) for c in contours])
    largest = int(np.argmax(areas))
    mask = np.zeros_like(binary)
    cv2.drawContours(mask, contours, largest, 255, thickness=cv2.FILLED)
    histogram = cv2.calcHist([blurred], [0], cv2.bitwise_not(binary), [256], [0, 256]).ravel()
    median = _histogram_median(histogram)
    levels = np.arange(256)
    deviations = np.bincount(np.abs(levels - median), weights=histogram, minlength=256)
    spread = 1.4826 * _histogram_median(deviations)
    contrast = float(cv2.mean(blurred, mask)[0] - median)
    min_area = max(20.0, 1e-5 * gray.size)
    if areas[largest] < min_area or contrast < max(_MIN_CONTRAST_DN, min_contrast_sigma * spread):
        return SpotDetection((), float(threshold), contrast)
    height, width = gray.shape
    order = np.argsort(-areas)
    spots = tuple(
        Spot(
            contour_px=contours[i].astype(float),
            area_px=float(areas[i]),
            touches_border=bool(
                np.any(contours[i] == 0)
                or np.any(contours[i][:, 0] == width - 1)
                or np.any(contours[i][:, 1] == height - 1)
            ),
        )
        for i in order
        if areas[i] >= _MIN_AREA_FRACTION * areas[largest]
    )
    return SpotDetection(spots, float(threshold), contrast)


def outer_boundary(spot: Spot, tolerance_px: float = 1.5) -> Spot:
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
    contour = spot.contour_px.astype(np.float32).reshape(-1, 1, 2)
    hull = cv2.convexHull(contour)
    distance = np.array([cv2.pointPolygonTest(hull, (float(u), float(v)), True) for u, v in spot.contour_px])
    outer = spot.contour_px[distance <= tolerance_px]
    if len(outer) < _MIN_CONTOUR_POINTS:
        return spot
    return replace(spot, contour_px=outer)


def _srgb_to_linear(codes: np.ndarray) -> np.ndarray:
    values = codes.astype(np.float64)
    return np.where(values <= 0.04045, values / 12.92, ((values + 0.055) / 1.055) ** 2.4).astype(np.float32)


_LINEAR_8 = _srgb_to_linear(np.arange(256) / 255.0)
_LINEAR_16 = _srgb_to_linear(np.arange(65536) / 65535.0)
# The LUTs are monotonic: clipping (linear >= 0.99) and brightness can be judged on the codes.
_FULL_SCALE_LINEAR = 0.99
_FULL_SCALE_8 = int(np.searchsorted(_LINEAR_8, _FULL_SCALE_LINEAR))
_FULL_SCALE_16 = int(np.searchsorted(_LINEAR_16, _FULL_SCALE_LINEAR))
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)  # Rec. 709, on linear values


def linear_luminance(image: np.ndarray) -> np.ndarray:
    """Linear luminance of an sRGB-encoded frame, full scale 1.

    Parameters
    ----------
    image : ndarray, shape (H, W), (H, W, 3) or (H, W, 4), uint8 or uint16
        sRGB-encoded grey or RGB(A), as the built-in renderer and Blender's
        standard view transform write.

    Returns
    -------
    ndarray, shape (H, W), float32
    """
    if image.dtype == np.uint8:
        linear = _LINEAR_8[image]
    elif image.dtype == np.uint16:
        linear = _LINEAR_16[image]
    else:
        raise ValueError(f"image must be 8-bit or 16-bit, got {image.dtype}")
    if linear.ndim == 2:
        return linear
    if linear.ndim == 3 and linear.shape[2] in (3, 4):
        return linear[..., :3] @ _LUMINANCE
    raise ValueError(f"image must be grey, RGB or RGBA, got shape {image.shape}")


@dataclass(frozen=True)
class SpotEdge:
    """A spot's boundary located to a fraction of a pixel.

    Attributes
    ----------
    pixels : ndarray, shape (N, 2)
        Edge points ``(u, v)``, one per valid ray, in ray order around the spot.
    ray_angles : ndarray, shape (N,)
        Direction of each point's ray from the spot's centre, radians.
    width_px : float
        Width of the edge: full width at half maximum of the mean intensity slope.
    saturated : bool
        Whether the spot reaches full scale somewhere.
    rays : int
        Rays cast; ``len(pixels)`` of them gave an edge.
    contrast_to_noise : float
        Median step across the edge over the pixel noise, on the rays with an
        edge (NaN without any): below some 20 the noise biases the edge's level.
    clipped_fraction : float
        Fraction of the samples inside the edge, where the plateau's line is
        fitted, at full scale in the channel read: a clipped plateau lowers the
        halfway level and moves the edge outward.
    """

    pixels: np.ndarray
    ray_angles: np.ndarray
    width_px: float
    saturated: bool
    rays: int
    contrast_to_noise: float = float("nan")
    clipped_fraction: float = 0.0


_STEP_PX = 0.5
_COARSE_LEVEL = 0.2
_PROFILE_RAYS = 64  # the median profile is taken over about this many rays
_COARSE_SAMPLES = 64
_COARSE_RAY_STRIDE = 2
_EDGE_MEDIAN_RAYS = 5  # coarse rays, about 9 rays


def detect_edge_subpixel(image: np.ndarray, spot: Spot) -> SpotEdge:
    """Locate a spot's edge to a fraction of a pixel, independently of the light's power.

    Rays are cast from the centre of the spot's coarse (Otsu) boundary across
    it, one per two pixels of perimeter (64 to 1024); see :func:`detect_edge_along_rays`.

    Parameters
    ----------
    image : ndarray
        The frame, sRGB-encoded (see :func:`linear_luminance`).
    spot : Spot
        The spot's coarse detection.

    Returns
    -------
    SpotEdge
    """
    contour = spot.contour_px.astype(float)
    perimeter = float(cv2.arcLength(spot.contour_px.astype(np.float32).reshape(-1, 1, 2), True))
    rays = int(np.clip(perimeter / 2.0, 64, 1024))
    centre, ray_angles, radii = rays_through_curve(contour, rays)
    return detect_edge_along_rays(image, centre, ray_angles, radii)


def rays_through_curve(curve_px: np.ndarray, rays: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Evenly spaced rays from a closed curve's centroid, and where each meets the curve.

    Parameters
    ----------
    curve_px : ndarray, shape (N, 2)
        Points ``(u, v)`` on a closed curve that is star-shaped about its centroid.
    rays : int

    Returns
    -------
    centre : ndarray, shape (2,)
    ray_angles : ndarray, shape (rays,)
        Directions, radians, from -pi.
    radii : ndarray, shape (rays,)
        Distance from the centre to the curve along each ray, pixels.
    """
    centre = curve_px.mean(axis=0)
    offsets = curve_px - centre
    curve_angles = np.arctan2(offsets[:, 1], offsets[:, 0])
    order = np.argsort(curve_angles)
    curve_radii = np.hypot(offsets[:, 0], offsets[:, 1])[order]
    ray_angles = np.linspace(-np.pi, np.pi, rays, endpoint=False)
    radii = np.interp(ray_angles, curve_angles[order], curve_radii, period=2 * np.pi)
    return centre, ray_angles, radii


def detect_edge_along_rays(
    image: np.ndarray, centre: np.ndarray, ray_angles: np.ndarray, radii: np.ndarray, *, align: bool = False
) -> SpotEdge:
    """Locate an edge to a fraction of a pixel on rays that cross it near ``radii``.

    On each ray the linear luminance (of the brightest channel that does not
    clip) is lightly smoothed; straight lines are fitted to the plateau inside
    the edge and to the background outside it, and the edge is put where the
    profile crosses the level halfway between them. Levels relative to the
    local plateau and background do not move when the power changes, and the
    lines follow the light's fall-off across the edge. The edge's width (from
    the median profile of all rays) sets where the lines are fitted. Rays
    without a clear crossing give no point. Only the pixels near the rays are
    read: the rays are the region of interest.

    With ``align`` the edge may lie anywhere within twice that distance of
    ``radii`` (a spot that moved since ``radii`` were predicted): a coarse
    pass over every second ray finds each ray's outermost fall through the
    level a fifth of the way from its lowest to its highest value (outside a
    spot there is only background, while a lit vessel stays above that
    level), with a running median over neighbouring rays against the clutter
    that remains; the fine pass is then centred there. The rays must then go
    around the spot in order.

    Parameters
    ----------
    image : ndarray
        The frame, sRGB-encoded (see :func:`linear_luminance`).
    centre : ndarray, shape (2,)
        The rays' origin ``(u, v)``, pixels.
    ray_angles : ndarray, shape (R,)
        Ray directions, radians.
    radii : ndarray, shape (R,)
        Expected distance of the edge from ``centre`` on each ray, pixels; the
        rays are sampled within ``0.15 * mean(radii) + 8`` pixels of it.
    align : bool
        Find each ray's edge coarsely first (see above).

    Returns
    -------
    SpotEdge
    """
    rays = len(ray_angles)
    crop = _linear_crop(image, centre, float(np.max(radii)) + edge_window_px(radii, align=align))
    if align:
        radii = _coarse_edge_radii(crop, centre, ray_angles, radii)
    steps, directions, profiles = _ray_profiles(crop, centre, ray_angles, radii, edge_window_px(radii), _STEP_PX)
    start = radii + steps[0]
    finite = np.all(np.isfinite(profiles), axis=1)
    if not finite.any():
        return SpotEdge(np.empty((0, 2)), np.empty(0), float("nan"), crop.saturated, rays)
    stride = 1 + int(np.sum(finite)) // _PROFILE_RAYS
    mean_profile = np.median(profiles[::stride][finite[::stride]], axis=0)
    mean_slope = -np.gradient(_smooth_rows(mean_profile[None, :])[0])
    width = max(_full_width_at_half_maximum(mean_slope), 3.0)  # samples
    middle = int(np.argmax(mean_slope))
    smooth = _smooth_rows(np.where(finite[:, None], profiles, mean_profile))
    count = len(steps)
    lines = smooth @ np.hstack(
        [
            _line_weights(count, middle - 2.5 * width, middle - 1.0 * width),
            _line_weights(count, middle + 1.0 * width, middle + 2.5 * width),
        ]
    )
    plateau_a, plateau_b, background_a, background_b = lines.T
    index = np.arange(count, dtype=float)
    above = smooth - 0.5 * ((plateau_a + background_a)[:, None] + (plateau_b + background_b)[:, None] * index)
    lo, hi = max(int(middle - width), 0), min(int(middle + width) + 1, count - 1)
    # The first fall from above the level to below it, searching outward within the edge.
    falls = (above[:, lo:hi] > 0) & (above[:, lo + 1 : hi + 1] <= 0)
    has_fall = falls.any(axis=1)
    first = lo + np.argmax(falls, axis=1)
    rows = np.arange(rays)
    a, b = above[rows, first], above[rows, first + 1]
    fraction = a / np.where(a - b > 0, a - b, 1.0)
    contrast = (plateau_a - background_a) + (plateau_b - background_b) * first
    noise = 1.4826 * np.median(np.abs(np.diff(profiles[::4][finite[::4]], axis=1))) / np.sqrt(2)  # every 4th ray
    valid = finite & has_fall & (contrast > max(4.0 * noise, 1e-4))
    edge_radii = start + (first + fraction) * _STEP_PX
    pixels = centre + edge_radii[:, None] * directions
    ratio = float(np.median(contrast[valid]) / max(noise, 1e-6)) if valid.any() else float("nan")
    inside = profiles[:, max(int(middle - 2.5 * width), 0) : max(int(middle - width), 1)][finite]
    clipped = float(np.count_nonzero(inside >= _FULL_SCALE_LINEAR)) / max(inside.size, 1)
    return SpotEdge(pixels[valid], ray_angles[valid], width * _STEP_PX, crop.saturated, rays, ratio, clipped)


def _coarse_edge_radii(crop: _LinearCrop, centre: np.ndarray, ray_angles: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Where each ray's profile last falls through a fifth of its range, within the aligned window.

    Every ``_COARSE_RAY_STRIDE``-th ray is read with ``_COARSE_SAMPLES``
    samples across the wide window; the edges are median-filtered over
    neighbouring rays, interpolated to all rays and kept within reach of the
    fine window (so that no pixel beyond ``edge_window_px(radii, align=True)``
    is read).
    """
    wide = edge_window_px(radii, align=True)
    coarse_angles, coarse_radii = ray_angles[::_COARSE_RAY_STRIDE], radii[::_COARSE_RAY_STRIDE]
    steps, _, profiles = _ray_profiles(crop, centre, coarse_angles, coarse_radii, wide, 2.0 * wide / _COARSE_SAMPLES)
    smooth = _smooth_rows(np.nan_to_num(profiles))
    low, high = smooth.min(axis=1), smooth.max(axis=1)
    above = smooth > (low + _COARSE_LEVEL * (high - low))[:, None]
    falls = above[:, :-1] & ~above[:, 1:]
    outermost = falls.shape[1] - 1 - np.argmax(falls[:, ::-1], axis=1)
    shift = np.where(falls.any(axis=1), steps[np.minimum(outermost + 1, len(steps) - 1)], 0.0)
    half = _EDGE_MEDIAN_RAYS // 2
    windows = sliding_window_view(np.concatenate([shift[-half:], shift, shift[:half]]), _EDGE_MEDIAN_RAYS)
    shift = np.partition(windows, half, axis=1)[:, half]  # running median, around the spot
    edge_radii = np.interp(ray_angles, coarse_angles, coarse_radii + shift, period=2 * np.pi)
    reach = wide - edge_window_px(radii)
    return np.clip(edge_radii, radii - reach, radii + reach)


def edge_window_px(radii: np.ndarray, *, align: bool = False) -> float:
    """How far from ``radii`` :func:`detect_edge_along_rays` reads each ray, pixels (twice as far with ``align``)."""
    return (2.0 if align else 1.0) * (0.15 * float(np.mean(radii)) + 8.0)


def _ray_profiles(
    crop: _LinearCrop, centre: np.ndarray, ray_angles: np.ndarray, radii: np.ndarray, half_window: float, step: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linear profiles along rays, sampled every ``step`` pixels within ``half_window`` of ``radii``.

    Returns the steps along each ray (pixels from ``radii``), the rays' unit
    directions (R, 2) and the profiles (R, steps), NaN off the crop.
    """
    steps = np.arange(-half_window, half_window + step, step)
    directions = np.column_stack([np.cos(ray_angles), np.sin(ray_angles)])
    distances = radii[:, None] + steps[None, :]
    map_u = (centre[0] - crop.origin[0] + distances * directions[:, :1]).astype(np.float32)
    map_v = (centre[1] - crop.origin[1] + distances * directions[:, 1:]).astype(np.float32)
    plane = crop.plane
    profiles = cv2.remap(plane, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    outside = (map_u < 0) | (map_v < 0) | (map_u > plane.shape[1] - 1) | (map_v > plane.shape[0] - 1)
    profiles[outside] = np.nan
    return steps, directions, profiles


def _smooth_rows(profiles: np.ndarray) -> np.ndarray:
    """Each row of (R, S) ``profiles`` smoothed by a Gaussian of 2 samples' sigma (mirrored at the ends)."""
    return cv2.GaussianBlur(profiles, (17, 1), 2.0, borderType=cv2.BORDER_REFLECT)


def _line_weights(count: int, start: float, stop: float) -> np.ndarray:
    """Weights (count, 2) whose product with a row gives the least-squares line ``a + b * index`` through it.

    Only the row's samples with index in [start, stop] count (at least two).
    """
    first, last = int(np.clip(np.ceil(start), 0, count - 2)), int(np.clip(np.floor(stop), 1, count - 1))
    last = max(last, first + 1)
    x = np.arange(first, last + 1, dtype=float)
    centred = x - x.mean()
    weights = np.zeros((count, 2))
    weights[first : last + 1, 1] = centred / np.sum(centred**2)  # slope
    weights[first : last + 1, 0] = 1.0 / len(x) - x.mean() * weights[first : last + 1, 1]  # intercept
    return weights


@dataclass(frozen=True)
class _LinearCrop:
    """One linear channel of a square of the image: ``plane[v - origin[1], u - origin[0]]``."""

    plane: np.ndarray
    origin: tuple[int, int]
    saturated: bool


def _linear_crop(image: np.ndarray, centre: np.ndarray, reach: float) -> _LinearCrop:
    """Linearise the pixels within ``reach`` of ``centre`` (clipped to the image), in one channel.

    The channel is the brightest that never clips there (else the least
    clipped one): a clipped channel bends the profile where it clips, while
    another channel still holds the edge's true shape. ``saturated`` tells
    whether any channel clipped.
    """
    height, width = image.shape[:2]
    u0, v0 = max(int(np.floor(centre[0] - reach)) - 1, 0), max(int(np.floor(centre[1] - reach)) - 1, 0)
    u1 = min(int(np.ceil(centre[0] + reach)) + 2, width)
    v1 = min(int(np.ceil(centre[1] + reach)) + 2, height)
    crop = image[v0:v1, u0:u1]
    channels = [crop] if crop.ndim == 2 else cv2.split(crop)[:3]
    lut, full_scale = (_LINEAR_8, _FULL_SCALE_8) if image.dtype == np.uint8 else (_LINEAR_16, _FULL_SCALE_16)
    brightest = np.array([cv2.minMaxLoc(c)[1] for c in channels])
    clipped = np.array(
        [
            cv2.countNonZero(cv2.compare(c, full_scale, cv2.CMP_GE)) if m >= full_scale else 0
            for c, m in zip(channels, brightest, strict=True)
        ]
    )
    channel = int(np.argmax(np.where(clipped == 0, brightest, -1))) if np.any(clipped == 0) else int(np.argmin(clipped))
    plane = channels[channel]
    linear = cv2.LUT(plane, lut) if plane.dtype == np.uint8 else lut[plane]
    return _LinearCrop(linear, (u0, v0), bool(np.any(clipped)))


def _full_width_at_half_maximum(values: np.ndarray) -> float:
    """Width, in samples, of the region around the maximum above half of it."""
    peak = int(np.nanargmax(values))
    half = 0.5 * values[peak]
    left = peak
    while left > 0 and values[left - 1] > half:
        left -= 1
    right = peak
    while right < len(values) - 1 and values[right + 1] > half:
        right += 1
    return float(right - left + 1)
