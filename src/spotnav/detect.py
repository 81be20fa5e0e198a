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
from numba import njit

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
    crop = _linear_crop(image, centre, float(np.max(radii)) + edge_window_px(radii, align=align))
    offset = np.asarray(centre, dtype=float) - crop.origin
    angles, radii = np.asarray(ray_angles, dtype=float), np.asarray(radii, dtype=float)
    if align:
        # Every _COARSE_RAY_STRIDE-th ray, _COARSE_SAMPLES samples across the wide window; the edge kept within
        # the fine window's reach (no pixel beyond edge_window_px(radii, align=True) is read).
        wide = edge_window_px(radii, align=True)
        steps = _window_steps(wide, 2.0 * wide / _COARSE_SAMPLES)
        radii = _aligned_radii(crop.plane, offset, angles, radii, steps, wide - edge_window_px(radii))
    edge_radii, valid, width, ratio, clipped = _read_edges(
        crop.plane, offset, angles, radii, _window_steps(edge_window_px(radii), _STEP_PX)
    )
    pixels = centre + edge_radii[valid, None] * np.column_stack([np.cos(angles[valid]), np.sin(angles[valid])])
    return SpotEdge(pixels, angles[valid], width * _STEP_PX, crop.saturated, len(angles), ratio, clipped)


def _window_steps(half_window: float, step: float) -> np.ndarray:
    """Samples every ``step`` pixels from ``-half_window`` to ``half_window``."""
    return np.arange(-half_window, half_window + step, step)


def edge_window_px(radii: np.ndarray, *, align: bool = False) -> float:
    """How far from ``radii`` :func:`detect_edge_along_rays` reads each ray, pixels (twice as far with ``align``)."""
    return (2.0 if align else 1.0) * (0.15 * float(np.mean(radii)) + 8.0)


# The compiled kernels below read rays one sample at a time: a frame's few thousand samples cost
# microseconds, where array calls would cost tens of microseconds each (tracking's budget is 5 ms).
_SMOOTHING = cv2.getGaussianKernel(17, 2.0).ravel()  # Gaussian of 2 samples' sigma


@njit(cache=True)
def _sample_rays(
    plane: np.ndarray, offset: np.ndarray, ray_angles: np.ndarray, radii: np.ndarray, steps: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear samples (R, S) of ``plane`` at ``offset + (radii + steps) * direction``, NaN off the plane.

    Also returns which rays (R,) lie wholly on the plane.
    """
    height, width = plane.shape
    profiles = np.full((len(ray_angles), len(steps)), np.nan)
    inside = np.zeros(len(ray_angles), dtype=np.bool_)
    if height < 2 or width < 2:
        return profiles, inside
    for r in range(len(ray_angles)):
        inside[r] = True
        cos, sin = np.cos(ray_angles[r]), np.sin(ray_angles[r])
        for s in range(len(steps)):
            u = offset[0] + (radii[r] + steps[s]) * cos
            v = offset[1] + (radii[r] + steps[s]) * sin
            if not (0.0 <= u <= width - 1 and 0.0 <= v <= height - 1):
                inside[r] = False
                continue
            iu, iv = min(int(u), width - 2), min(int(v), height - 2)
            fu, fv = u - iu, v - iv
            top = (1.0 - fu) * plane[iv, iu] + fu * plane[iv, iu + 1]
            bottom = (1.0 - fu) * plane[iv + 1, iu] + fu * plane[iv + 1, iu + 1]
            profiles[r, s] = (1.0 - fv) * top + fv * bottom
    return profiles, inside


@njit(cache=True)
def _smooth(values: np.ndarray, kernel: np.ndarray, start: int, stop: int) -> np.ndarray:
    """``values`` (S,) convolved with ``kernel`` (odd length), mirrored at the ends (``fedcba|abcdef|fedcba``).

    Only samples ``start`` to ``stop`` (exclusive) are computed, the others are NaN. Rows shorter
    than half the kernel are mirrored once, then held.
    """
    count, half = len(values), len(kernel) // 2
    start, stop = max(start, 0), min(stop, count)
    padded = np.empty(count + 2 * half)
    for j in range(count + 2 * half):
        i = j - half
        if i < 0:
            i = min(-i - 1, count - 1)
        elif i >= count:
            i = max(2 * count - i - 1, 0)
        padded[j] = values[i]
    # Taps outside, samples inside, indices counted from 0 (no negative-index checks): the inner loop vectorises.
    source, part = padded[start:], np.zeros(max(stop - start, 0))
    for k in range(len(kernel)):
        for i in range(len(part)):
            part[i] += kernel[k] * source[i + k]
    smooth = np.full(count, np.nan)
    for i in range(len(part)):
        smooth[start + i] = part[i]
    return smooth


@njit(cache=True)
def _fit_line(values: np.ndarray, start: float, stop: float) -> tuple[float, float]:
    """Least-squares line ``a + b * index`` through the samples with index in [start, stop] (at least two)."""
    count = len(values)
    first = min(max(int(np.ceil(start)), 0), count - 2)
    last = max(min(max(int(np.floor(stop)), 1), count - 1), first + 1)
    index_mean = 0.5 * (first + last)
    value_mean = np.mean(values[first : last + 1])
    covariance, variance = 0.0, 0.0
    for i in range(first, last + 1):
        covariance += (i - index_mean) * (values[i] - value_mean)
        variance += (i - index_mean) ** 2
    slope = covariance / variance
    return value_mean - index_mean * slope, slope


@njit(cache=True)
def _full_width_at_half_maximum(values: np.ndarray) -> float:
    """Width, in samples, of the region around the maximum above half of it."""
    peak = int(np.argmax(values))
    half = 0.5 * values[peak]
    left = peak
    while left > 0 and values[left - 1] > half:
        left -= 1
    right = peak
    while right < len(values) - 1 and values[right + 1] > half:
        right += 1
    return float(right - left + 1)


@njit(cache=True)
def _every_nth(selected: np.ndarray, n: int) -> np.ndarray:
    """Indices of every ``n``-th entry of ``selected`` (R,) that is True."""
    chosen = np.empty(len(selected), dtype=np.int64)
    count = 0
    for r in range(0, len(selected), n):
        if selected[r]:
            chosen[count] = r
            count += 1
    return chosen[:count]


@njit(cache=True)
def _read_edges(
    plane: np.ndarray, offset: np.ndarray, ray_angles: np.ndarray, radii: np.ndarray, steps: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, float, float]:
    """The fine pass of :func:`detect_edge_along_rays` on rays sampled at ``steps`` (S,) around ``radii`` (R,).

    Returns each ray's edge distance from the centre (R,), whether it is valid
    (R,), the edge's width in samples, the median contrast over the noise and
    the clipped fraction of the plateau.
    """
    rays, count = len(ray_angles), len(steps)
    profiles, finite = _sample_rays(plane, offset, ray_angles, radii, steps)
    edge_radii = np.full(rays, np.nan)
    valid = np.zeros(rays, dtype=np.bool_)
    if not finite.any():
        return edge_radii, valid, np.nan, np.nan, 0.0
    # The median profile, over about _PROFILE_RAYS rays, gives the edge's place and width in the window.
    chosen = _every_nth(finite, 1 + finite.sum() // _PROFILE_RAYS)
    column = np.empty(len(chosen))
    mean_profile = np.empty(count)
    for s in range(count):
        for j in range(len(chosen)):
            column[j] = profiles[chosen[j], s]
        mean_profile[s] = np.median(column)
    mean_smooth = _smooth(mean_profile, _SMOOTHING, 0, count)
    mean_slope = np.empty(count)  # minus the gradient: central differences, one-sided at the ends
    for s in range(1, count - 1):
        mean_slope[s] = 0.5 * (mean_smooth[s - 1] - mean_smooth[s + 1])
    mean_slope[0], mean_slope[-1] = mean_smooth[0] - mean_smooth[1], mean_smooth[-2] - mean_smooth[-1]
    width = max(_full_width_at_half_maximum(mean_slope), 3.0)  # samples
    middle = int(np.argmax(mean_slope))
    lo, hi = max(int(middle - width), 0), min(int(middle + width) + 1, count - 1)
    quiet = _every_nth(finite, 4)
    steps_between = np.empty(len(quiet) * (count - 1))
    for j in range(len(quiet)):
        for s in range(count - 1):
            steps_between[j * (count - 1) + s] = abs(profiles[quiet[j], s + 1] - profiles[quiet[j], s])
    noise = 1.4826 * np.median(steps_between) / np.sqrt(2.0)
    contrast = np.zeros(rays)
    # Only the samples the lines and the crossing read are smoothed.
    needed = (max(int(np.floor(middle - 2.5 * width)) - 1, 0), int(np.ceil(middle + 2.5 * width)) + 2)
    for r in range(rays):
        smooth = _smooth(profiles[r], _SMOOTHING, needed[0], needed[1]) if finite[r] else mean_smooth
        plateau_a, plateau_b = _fit_line(smooth, middle - 2.5 * width, middle - 1.0 * width)
        background_a, background_b = _fit_line(smooth, middle + 1.0 * width, middle + 2.5 * width)
        level_a, level_b = 0.5 * (plateau_a + background_a), 0.5 * (plateau_b + background_b)
        # The first fall from above the halfway level to below it, searching outward within the edge.
        first, has_fall = lo, False
        for i in range(lo, hi):
            if smooth[i] - level_a - level_b * i > 0 and smooth[i + 1] - level_a - level_b * (i + 1) <= 0:
                first, has_fall = i, True
                break
        a = smooth[first] - level_a - level_b * first
        b = smooth[first + 1] - level_a - level_b * (first + 1)
        fraction = a / (a - b) if a - b > 0 else a
        contrast[r] = (plateau_a - background_a) + (plateau_b - background_b) * first
        valid[r] = finite[r] and has_fall and contrast[r] > max(4.0 * noise, 1e-4)
        edge_radii[r] = radii[r] + steps[0] + (first + fraction) * (steps[1] - steps[0])
    contrast_valid = contrast[_every_nth(valid, 1)]
    ratio = np.median(contrast_valid) / max(noise, 1e-6) if len(contrast_valid) else np.nan
    plateau = range(max(int(middle - 2.5 * width), 0), min(max(int(middle - width), 1), count))
    clipped_samples, samples = 0, 0
    for r in range(rays):
        if finite[r]:
            for s in plateau:
                clipped_samples += profiles[r, s] >= _FULL_SCALE_LINEAR
                samples += 1
    clipped = clipped_samples / max(samples, 1)
    return edge_radii, valid, width, ratio, clipped


@njit(cache=True)
def _aligned_radii(
    plane: np.ndarray, offset: np.ndarray, ray_angles: np.ndarray, radii: np.ndarray, steps: np.ndarray, reach: float
) -> np.ndarray:
    """The coarse pass of :func:`detect_edge_along_rays`: each ray's edge, within ``reach`` of ``radii`` (R,).

    Every ``_COARSE_RAY_STRIDE``-th ray is sampled at ``steps`` (S,) around
    ``radii``; its edge is the outermost fall through ``_COARSE_LEVEL`` of its
    smoothed range. The edges are median-filtered over ``_EDGE_MEDIAN_RAYS``
    neighbours around the spot and interpolated, in angle, to every ray.
    """
    coarse = np.arange(0, len(ray_angles), _COARSE_RAY_STRIDE)
    rays, count = len(coarse), len(steps)
    profiles, _ = _sample_rays(plane, offset, ray_angles[coarse], radii[coarse], steps)
    shift = np.zeros(rays)
    for r in range(rays):
        for i in range(count):
            if np.isnan(profiles[r, i]):
                profiles[r, i] = 0.0  # off the image: dark
        smooth = _smooth(profiles[r], _SMOOTHING, 0, count)
        low, high = smooth.min(), smooth.max()
        threshold = low + _COARSE_LEVEL * (high - low)
        for i in range(count - 2, -1, -1):
            if smooth[i] > threshold and not smooth[i + 1] > threshold:
                shift[r] = steps[i + 1]
                break
    half = _EDGE_MEDIAN_RAYS // 2
    coarse_radii, window = np.empty(rays), np.empty(_EDGE_MEDIAN_RAYS)
    for r in range(rays):
        for k in range(_EDGE_MEDIAN_RAYS):
            window[k] = shift[(r + k - half) % rays]
        coarse_radii[r] = radii[coarse[r]] + np.median(window)
    aligned = np.empty(len(ray_angles))
    for j in range(len(ray_angles)):
        before, after = j // _COARSE_RAY_STRIDE, (j // _COARSE_RAY_STRIDE + 1) % rays
        gap = (ray_angles[coarse[after]] - ray_angles[coarse[before]]) % (2.0 * np.pi)
        weight = (ray_angles[j] - ray_angles[coarse[before]]) % (2.0 * np.pi) / gap if gap > 0 else 0.0
        edge = (1.0 - weight) * coarse_radii[before] + weight * coarse_radii[after]
        aligned[j] = min(max(edge, radii[j] - reach), radii[j] + reach)
    return aligned


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
    lut, full_scale = (_LINEAR_8, _FULL_SCALE_8) if image.dtype == np.uint8 else (_LINEAR_16, _FULL_SCALE_16)
    plane, saturated = _linear_channel(crop if crop.ndim == 3 else crop[:, :, None], lut, full_scale)
    return _LinearCrop(plane, (u0, v0), saturated)


@njit(cache=True)
def _linear_channel(crop: np.ndarray, lut: np.ndarray, full_scale: int) -> tuple[np.ndarray, bool]:
    """One channel (of the first three) of ``crop`` (H, W, C) through ``lut``, and whether any channel clips.

    The channel is the brightest that never reaches ``full_scale``, else the least clipped one.
    """
    height, width, channels = crop.shape[0], crop.shape[1], min(crop.shape[2], 3)
    brightest, clipped = np.zeros(channels, dtype=np.int64), np.zeros(channels, dtype=np.int64)
    for v in range(height):
        row = crop[v]
        for u in range(width):
            for c in range(channels):
                if row[u, c] > brightest[c]:
                    brightest[c] = row[u, c]
    for c in range(channels):
        if brightest[c] >= full_scale:  # only then count, in an extra pass
            count = 0
            for v in range(height):
                row = crop[v]
                for u in range(width):
                    count += row[u, c] >= full_scale
            clipped[c] = count
    chosen = int(np.argmin(clipped))
    for c in range(channels):
        if clipped[c] == 0 and (clipped[chosen] > 0 or brightest[c] > brightest[chosen]):
            chosen = c
    plane = np.empty((height, width), dtype=np.float32)
    for v in range(height):
        row = crop[v]
        for u in range(width):
            plane[v, u] = lut[row[u, chosen]]
    return plane, clipped.sum() > 0
