"""A clipped spot's edge read from its flank (:func:`fit_clipped_edges`). Along a ray from the spot's centre, each
pixel's light is modelled as ``min(amplitude * S(x - e) + background(x), full_scale)``, with ``x`` the pixel centre's
distance from the spot's centre along the ray, ``e`` the ray's edge (the half-light point) and ``S`` the band's
smoothstep over the pixel's footprint (:func:`spotnav.image.photometry.pixel_light`); the model's pixels are
interpolated bilinearly at the ray's samples, as the frame's pixels are, and compared with them: clipped pixels are
clipped in the model too, so no sample needs to be treated apart. Where the plateau clips, the half level between
plateau and background is gone, but the unclipped flank's shape still pins the edge: the spot's amplitude (how far
over full scale it is) is fitted from the flank of all its clipped rays at once, each ray's edge from its own
samples. Rays whose plateau does not clip keep the half level (:func:`spotnav.image.rays.detect_edge_along_rays`),
which the fundus's albedo under each ray does not move. Where the noise beside the spot shows the encoded frame
blurred, each pixel's clipped light is encoded by the camera's response, blurred across the edge and decoded
(:func:`_pixel_model`), and the blur's uncertainty moves the edges with it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from spotnav.image.photometry import _inverse_profile, _pixel_light_rate, pixel_light

__all__ = ["fit_clipped_edges"]


_STEP_LIMIT_PX = 1.0  # a ray's edge moves at most this far in one Gauss-Newton step
_HALVINGS = 5
_AMPLITUDE_STEP = 0.25  # natural log: the amplitudes tried are a third of a stop apart ...
_AMPLITUDE_GRID = 36  # ... from the step's (a plateau just at full scale) to 8000 times it
# The blur beyond the pixels' own box (sigma, pixels). One value: searched with the amplitude (0.03 to 2 px), a blur
# and a brighter light traded for each other along the flank and tips erred by up to 0.13 mm at +6 stops (1024 px).
_BLUR_PX = 0.03
# The encoded frame's blur across a ray, a Gaussian, summed at this spacing out to this many sigmas. Gauss-Hermite
# nodes (9) missed the clip's kink: a clipped flank 2 px blurred was modelled 0.04 of full scale off, tips 0.05 mm.
_FRAME_BLUR_STEP_PX = 0.5
_FRAME_BLUR_REACH = 3.0
_RAY_STEPS = 3  # Gauss-Newton steps of a ray's edge at each amplitude and blur
# About this many rays choose the amplitude, coarse then fine. Fewer for the coarse search (8) found the flank's cost
# flat from 1 to 100 times full scale and chose an amplitude 60 times too high (a tip 0.043 mm off at 0.5 W).
_GRID_RAYS = 32
_COARSE_STRIDE = 4  # the coarse search's amplitudes are this many of the grid's apart
_BACKGROUND_REACH_PX = 6.0  # a clipped ray is read this far past its crossing and band: the last 4 px are background
# How far the flank's shape may mislead the amplitude (natural log) beyond its noise: a blur beyond the pixels' box
# (defocus, the light's own size) is not fitted. Measured on the built-in renderer (1024 px, helix, +4.5 and +6
# stops, a Gaussian for the box): the tips erred by up to 6 of the noise's sigmas alone, 3.1 with 0.4 here.
_FLANK_MODEL_SIGMA = 0.5
# ... in full from this far over full scale (natural log), from _FLANK_MODEL_FLOOR of it at full scale. Measured at
# 1024 px, 0.25 and 0.5 W, thesis's exposure, 25 tips a path: spots that barely clip erred by up to 0.032 mm, 4.7
# times sqrt(3) sigma_mm at a floor of 0 (the rate at which their edges move with the amplitude is the largest
# there); the floor is twice what covered them.
_FLANK_MODEL_REACH = 1.0
_FLANK_MODEL_FLOOR = 0.4


@njit(cache=True)
def _on_curve(x: float, grid: np.ndarray, values: np.ndarray) -> tuple[float, float]:
    """The piecewise-linear curve through ``(grid, values)`` (increasing) at ``x``, and its slope there."""
    i: int | np.intp = min(max(np.searchsorted(grid, x) - 1, 0), len(grid) - 2)  # type: ignore[assignment]  # typeshed's max(): intp and int have no common type
    slope = (values[i + 1] - values[i]) / (grid[i + 1] - grid[i])
    return values[i] + slope * (x - grid[i]), slope


@njit(cache=True)
def _pixel_model(
    x: float,
    cos: float,
    sin: float,
    edge: float,
    amplitude: float,
    band: float,
    blur: tuple[float, float],
    background: tuple[float, float, float],
    full_scale: float,
    response: tuple[np.ndarray, np.ndarray],
) -> tuple[float, float]:
    """The model's light at a pixel whose centre lies ``x`` pixels along a ray, and its rate by the ray's edge.

    ``blur`` is the light's blur beyond the pixel's square and the encoded
    frame's (sigmas, pixels). The light is clipped at ``full_scale``; where
    the encoded frame was blurred, the clipped light is encoded by
    ``response`` (:func:`spotnav.optics.edgeblur.response_curve`), blurred across
    the edge (along the ray, every ``_FRAME_BLUR_STEP_PX``) and decoded.
    """
    if blur[1] == 0.0:
        base = max(background[0] + background[1] * (x - background[2]), 0.0)
        level = amplitude * pixel_light(x - edge, band, cos, sin, blur[0]) + base
        if level >= full_scale:
            return full_scale, 0.0
        return level, -amplitude * _pixel_light_rate(x - edge, band, cos, sin, blur[0])
    light_grid, value_grid = response
    top = _on_curve(full_scale, light_grid, value_grid)[0]
    reach = math.ceil(_FRAME_BLUR_REACH * blur[1] / _FRAME_BLUR_STEP_PX)
    code = code_rate = weights = 0.0
    for k in range(-reach, reach + 1):
        offset = k * _FRAME_BLUR_STEP_PX
        weight = math.exp(-0.5 * (offset / blur[1]) ** 2)
        weights += weight
        at = x + offset
        base = max(background[0] + background[1] * (at - background[2]), 0.0)
        level = amplitude * pixel_light(at - edge, band, cos, sin, blur[0]) + base
        if level >= full_scale:
            code += weight * top
            continue
        encoded, slope = _on_curve(level, light_grid, value_grid)
        code += weight * encoded
        code_rate -= weight * slope * amplitude * _pixel_light_rate(at - edge, band, cos, sin, blur[0])
    light, slope = _on_curve(code / weights, value_grid, light_grid)
    return light, slope * code_rate / weights


@njit(cache=True)
def _sample_model(
    offset: np.ndarray,
    cos: float,
    sin: float,
    position: float,
    width: int,
    height: int,
    edge: float,
    amplitude: float,
    band: float,
    blur: tuple[float, float],
    background: tuple[float, float, float],
    full_scale: float,
    response: tuple[np.ndarray, np.ndarray],
) -> tuple[float, float]:
    """The model's bilinear sample at ``position`` pixels along a ray, and its rate by the ray's edge.

    The four pixels the sample reads are modelled at their centres (their
    distance along the ray; :func:`_pixel_model`) and interpolated as
    :func:`spotnav.image.profiles._sample_rays` interpolates the frame's.
    ``background`` is ``(level, slope, where)``: its light ``where`` pixels
    along the ray and its slope per pixel outward.
    """
    u = offset[0] + position * cos
    v = offset[1] + position * sin
    iu, iv = min(int(u), width - 2), min(int(v), height - 2)
    fu, fv = u - iu, v - iv
    value = rate_edge = 0.0
    for corner in range(4):
        du, dv = corner % 2, corner // 2
        weight = (fu if du else 1.0 - fu) * (fv if dv else 1.0 - fv)
        if weight == 0.0:
            continue
        x = (iu + du - offset[0]) * cos + (iv + dv - offset[1]) * sin
        level, rate = _pixel_model(x, cos, sin, edge, amplitude, band, blur, background, full_scale, response)
        value += weight * level
        rate_edge += weight * rate
    return value, rate_edge


@njit(cache=True)
def _ray_cost(
    pixels_shape: tuple[int, int],
    offset: np.ndarray,
    angle: float,
    sample_radii: np.ndarray,
    data: np.ndarray,
    first: int,
    last: int,
    edge: float,
    amplitude: float,
    band: float,
    blur: tuple[float, float],
    background: tuple[float, float, float],
    full_scale: float,
    response: tuple[np.ndarray, np.ndarray],
) -> float:
    """Sum of squared differences between a ray's samples ``first`` to ``last`` and the model's."""
    height, width = pixels_shape
    cos, sin = math.cos(angle), math.sin(angle)
    total = 0.0
    for k in range(first, last + 1):
        model = _sample_model(
            offset, cos, sin, sample_radii[k], width, height, edge, amplitude, band, blur, background, full_scale,
            response,
        )[0]  # fmt: skip
        total += (min(data[k], full_scale) - model) ** 2
    return total


@njit(cache=True)
def _ray_edge(
    shape: tuple[int, int],
    offset: np.ndarray,
    angle: float,
    sample_radii: np.ndarray,
    data: np.ndarray,
    first: int,
    last: int,
    edge: float,
    amplitude: float,
    band: float,
    blur: tuple[float, float],
    background: tuple[float, float, float],
    full_scale: float,
    response: tuple[np.ndarray, np.ndarray],
    steps: int,
) -> tuple[float, float]:
    """A ray's edge after ``steps`` Gauss-Newton steps from ``edge`` (the spot's amplitude and blur held), and its
    cost there.

    A step that raises the cost is halved until it does not (``_HALVINGS`` times at most, then the edge stays):
    on a steep clipped flank a full step can leap where the model is clipped or dark throughout and has no
    gradient left to come back by.
    """
    height, width = shape
    cos, sin = math.cos(angle), math.sin(angle)
    cost = _ray_cost(
        shape, offset, angle, sample_radii, data, first, last, edge, amplitude, band, blur, background, full_scale,
        response,
    )  # fmt: skip
    for _ in range(steps):
        normal = gradient = 0.0
        for k in range(first, last + 1):
            model, rate = _sample_model(
                offset, cos, sin, sample_radii[k], width, height, edge, amplitude, band, blur, background, full_scale,
                response,
            )  # fmt: skip
            normal += rate * rate
            gradient += rate * (min(data[k], full_scale) - model)
        if not normal > 0.0:
            break
        move = min(max(gradient / normal, -_STEP_LIMIT_PX), _STEP_LIMIT_PX)
        for _ in range(_HALVINGS):
            tried = _ray_cost(
                shape, offset, angle, sample_radii, data, first, last, edge + move, amplitude, band, blur,
                background, full_scale, response,
            )  # fmt: skip
            if tried <= cost:
                edge, cost = edge + move, tried
                break
            move *= 0.5
    return edge, cost


@njit(cache=True)
def _profile_cost(
    shape: tuple[int, int],
    offset: np.ndarray,
    angles: np.ndarray,
    sample_radii: np.ndarray,
    profiles: np.ndarray,
    crossings: np.ndarray,
    rays: np.ndarray,
    firsts: np.ndarray,
    lasts: np.ndarray,
    bands: np.ndarray,
    backgrounds: np.ndarray,
    full_scale: float,
    log_amplitude: float,
    blurs: np.ndarray,
    response: tuple[np.ndarray, np.ndarray],
    edges: np.ndarray,
) -> float:
    """The spot's cost at an amplitude and each ray's blurs (``blurs`` (R, 2): the light's and the frame's,
    :func:`_pixel_model`), each of ``rays``' edges fitted (written into ``edges``)."""
    amplitude = math.exp(log_amplitude)
    total = 0.0
    for r in rays:
        blur = (blurs[r, 0], blurs[r, 1])
        background = (backgrounds[r, 0], backgrounds[r, 1], crossings[r])
        level = min(max(0.5 * (full_scale - backgrounds[r, 0]) / amplitude, 1e-9), 1.0 - 1e-9)
        # The start: the light's fall with both blurs in it (the frame's as if in light: near enough to start from).
        start = crossings[r] - _inverse_profile(
            level, bands[r], math.hypot(blur[0], blur[1]), math.cos(angles[r]), math.sin(angles[r])
        )
        edges[r], cost = _ray_edge(
            shape, offset, angles[r], sample_radii[r], profiles[r], firsts[r], lasts[r], start, amplitude, bands[r],
            blur, background, full_scale, response, _RAY_STEPS,
        )  # fmt: skip
        total += cost
    return total


@njit(cache=True)
def fit_clipped_edges(
    shape: tuple[int, int],
    offset: np.ndarray,
    angles: np.ndarray,
    sample_radii: np.ndarray,
    profiles: np.ndarray,
    crossings: np.ndarray,
    usable: np.ndarray,
    backgrounds: np.ndarray,
    full_scale: float,
    bands: np.ndarray,
    noise: float,
    frame_blur: tuple[float, float],
    response: tuple[np.ndarray, np.ndarray],
    light_blurs: np.ndarray,
    light_blur_share: float,
) -> tuple[np.ndarray, np.ndarray, float, float, float]:
    """Each ray's edge (its half-light point) from the photometric model, where the spot's plateau clips.

    The spot's amplitude is one for all its rays: a clipped ray
    alone cannot tell a brighter light from an edge further in (both move
    where it reaches full scale), while the flank's shape over all the rays,
    each crossing the pixels at another phase, does. They are searched on a
    grid (amplitudes a third of a stop apart: every fourth first, then
    those near the best; ``_BLUR_PX`` and the lens's ``light_blurs`` hold the blur
    beyond the pixel's square), each ray's edge fitted at every node, and refined by a
    parabola about the best node; each ray's edge is then fitted at the
    optimum. How well the flank pins the amplitude (the parabola's curvature
    against the residuals' variance, and ``_FLANK_MODEL_SIGMA`` for the blur's
    shape) is how far every edge may shift together. A frame blurred after its
    encoding by a known blur (``frame_blur``) is modelled so
    (:func:`_pixel_model`), and the blur's uncertainty moves the edges too; so does the light's blur's.

    Parameters
    ----------
    shape : (int, int)
        The pixels' height and width (the crop the rays were sampled on).
    offset : ndarray, shape (2,)
        The rays' origin in the crop's pixels.
    angles : ndarray, shape (R,)
        Ray directions, radians.
    sample_radii : ndarray, shape (R, S)
        Each sample's distance from the origin along its ray, pixels.
    profiles : ndarray, shape (R, S)
        The samples, linear light (bilinear in the pixels; NaN off the crop).
    crossings : ndarray, shape (R,)
        Where each ray crosses the level halfway between its clipped plateau and its background, pixels from
        the origin (the smoothed samples' crossing); the fitted rays' are replaced by their raw samples'.
    usable : ndarray, shape (R,), bool
        The rays to fit.
    backgrounds : ndarray, shape (R, 2)
        Each ray's background at its crossing and its slope per pixel outward, linear light; the fitted rays'
        are replaced by the median of their raw samples past the band (slope 0).
    full_scale : float
        The light at which the camera clips.
    bands : ndarray, shape (R,)
        The soft band's width along each ray, pixels (:func:`spotnav.image.photometry.ray_bands`).
    noise : float
        The samples' noise, linear light: flank samples lie this far from both ends.
    frame_blur : (float, float)
        The encoded frame's blur (a Gaussian's sigma, pixels; 0: none) and its 1 sigma.
    response : (ndarray, ndarray)
        Light and its encoded value (:func:`spotnav.optics.edgeblur.response_curve`): where the frame's blur acts.
    light_blurs : ndarray, shape (R,)
        The light's blur at each ray's crossing by the lens's depth of field (a Gaussian's sigma, pixels,
        :func:`spotnav.image.photometry.ray_light_blurs`; 0: in focus): with ``_BLUR_PX`` in quadrature, the blur
        before the clip. A blur of the light and a brighter light trade along a clipped flank, so it is stated
        (or calibrated), not fitted here.
    light_blur_share : float
        Their 1 sigma, a share of themselves (the aperture's: the blur is proportional to it).

    Returns
    -------
    edges : ndarray, shape (R,)
        Each ray's half-light point, pixels from the origin (NaN where not fitted).
    flank : ndarray, shape (R,), int
        How many of each ray's samples lie on the unclipped flank (over the background by 4 noises and under
        full scale).
    log_amplitude : float
        The spot's amplitude, natural log of its plateau's light (full scale 1).
    blur : float
        The spot's light's blur (the median ray's), pixels.
    shift_sigma : float
        1-sigma of a shift of every edge together that the amplitude's and the two blurs' uncertainties leave,
        pixels.
    """
    rays, count = profiles.shape
    edges = np.full(rays, np.nan)
    flank = np.zeros(rays, dtype=np.int64)
    chosen = np.flatnonzero(usable)
    if len(chosen) == 0:
        return edges, flank, np.nan, np.nan, np.nan
    step = sample_radii[chosen[0], 1] - sample_radii[chosen[0], 0]
    spread = 3.0 * frame_blur[0]  # the frame's blur spreads the flank this much further each way
    firsts, lasts = np.zeros(rays, dtype=np.int64), np.zeros(rays, dtype=np.int64)
    for r in chosen:
        # From inside the band (the clipped plateau: the model must clip there too) to past the flank's tail.
        firsts[r] = max(int((crossings[r] - 1.5 * bands[r] - 2.0 - spread - sample_radii[r, 0]) / step), 0)
        lasts[r] = min(
            int((crossings[r] + bands[r] + _BACKGROUND_REACH_PX + spread - sample_radii[r, 0]) / step) + 1, count - 1
        )
        while firsts[r] < lasts[r] and np.isnan(profiles[r, firsts[r]]):
            firsts[r] += 1
        while lasts[r] > firsts[r] and np.isnan(profiles[r, lasts[r]]):
            lasts[r] -= 1
        # The background: the raw samples past the band and the pixels' reach (the detector's line was fitted to
        # smoothed samples, which the sharp flank of a clipped spot still lifts near its edge).
        outside = min(
            max(int((crossings[r] + bands[r] + 2.0 + spread - sample_radii[r, 0]) / step), firsts[r]), lasts[r]
        )
        backgrounds[r, 0] = np.median(profiles[r, outside : lasts[r] + 1])
        backgrounds[r, 1] = 0.0
        # Where the raw samples last fall through the level halfway between full scale and the background: the
        # edges start from there (the smoothed crossing lies further out on a clipped flank).
        level = 0.5 * (full_scale + backgrounds[r, 0])
        for k in range(lasts[r] - 1, firsts[r] - 1, -1):
            if profiles[r, k] > level:
                fraction = (profiles[r, k] - level) / max(profiles[r, k] - profiles[r, k + 1], 1e-12)
                crossings[r] = sample_radii[r, k] + min(fraction, 1.0) * step
                break
        for k in range(firsts[r], lasts[r] + 1):
            if backgrounds[r, 0] + 4.0 * noise < profiles[r, k] < full_scale - max(noise, 1e-3):
                flank[r] += 1
    blurs = _ray_blurs(light_blurs, 0.0, frame_blur[0])
    grid_rays = chosen[:: max(len(chosen) // _GRID_RAYS, 1)]
    lowest = math.log(max(full_scale - np.median(backgrounds[chosen, 0]), 1e-6))
    log_amplitude, costs, j, curvature = _search_amplitude(
        shape, offset, angles, sample_radii, profiles, crossings, grid_rays, firsts, lasts, bands, backgrounds,
        full_scale, lowest, blurs, response, edges,
    )  # fmt: skip
    _profile_cost(
        shape, offset, angles, sample_radii, profiles, crossings, chosen, firsts, lasts, bands, backgrounds,
        full_scale, log_amplitude, blurs, response, edges,
    )  # fmt: skip
    # The amplitude's variance from the profile cost's curvature and the residuals' variance; how far the edges
    # move together per unit of log amplitude.
    samples = 0
    for r in grid_rays:
        samples += lasts[r] - firsts[r] + 1
    variance = max(costs[j] / max(samples - len(grid_rays) - 2, 1), noise * noise)
    moved = edges.copy()
    _profile_cost(
        shape, offset, angles, sample_radii, profiles, crossings, grid_rays, firsts, lasts, bands, backgrounds,
        full_scale, log_amplitude + _AMPLITUDE_STEP, blurs, response, moved,
    )  # fmt: skip
    rate = _mean_move(edges, moved, grid_rays) / _AMPLITUDE_STEP
    noise_variance = 2.0 * variance / curvature if curvature > 0.0 else _AMPLITUDE_STEP**2
    # The flank's shape misleads an amplitude the more of the flank is clipped: least at full scale, where the whole
    # band is seen.
    share = min(max((log_amplitude - lowest) / _FLANK_MODEL_REACH, _FLANK_MODEL_FLOOR), 1.0)
    model_sigma = _FLANK_MODEL_SIGMA * share
    shift_sigma = abs(rate) * math.sqrt(noise_variance + model_sigma**2)
    # Each blur one sigma either way, the amplitude searched again: a wider blur takes a brighter light (the frame's:
    # with the amplitude held, a spot's shift was 0.11 px against 0.30, a tip 0.04 mm off at 6.5 sigma_mm), and the
    # edges' move is not the same both ways (one way only, two tips of 16 were off by over 3 sigma_mm).
    light_move = frame_move = 0.0
    for sign in (-1.0, 1.0):
        if light_blur_share > 0.0:
            other = _ray_blurs(light_blurs, sign * light_blur_share, frame_blur[0])
            light_move = max(light_move, abs(_blur_move(
                shape, offset, angles, sample_radii, profiles, crossings, grid_rays, firsts, lasts, bands,
                backgrounds, full_scale, lowest, other, response, edges, moved,
            )))  # fmt: skip
        if frame_blur[0] > 0.0 and frame_blur[1] > 0.0:
            other = _ray_blurs(light_blurs, 0.0, max(frame_blur[0] + sign * frame_blur[1], 0.0))
            frame_move = max(frame_move, abs(_blur_move(
                shape, offset, angles, sample_radii, profiles, crossings, grid_rays, firsts, lasts, bands,
                backgrounds, full_scale, lowest, other, response, edges, moved,
            )))  # fmt: skip
    shift_sigma = math.sqrt(shift_sigma**2 + light_move**2 + frame_move**2)
    return edges, flank, log_amplitude, np.median(blurs[chosen, 0]), shift_sigma


@njit(cache=True)
def _ray_blurs(light_blurs: np.ndarray, share: float, frame_blur: float) -> np.ndarray:
    """Each ray's blurs (R, 2): the light's beyond the pixel's square (``_BLUR_PX`` and the lens's ``light_blurs``
    changed by ``share`` of themselves, in quadrature) and the frame's."""
    blurs = np.empty((len(light_blurs), 2))
    for r in range(len(light_blurs)):
        blurs[r, 0] = math.hypot(_BLUR_PX, max(1.0 + share, 0.0) * light_blurs[r])
        blurs[r, 1] = frame_blur
    return blurs


@njit(cache=True)
def _search_amplitude(
    shape: tuple[int, int],
    offset: np.ndarray,
    angles: np.ndarray,
    sample_radii: np.ndarray,
    profiles: np.ndarray,
    crossings: np.ndarray,
    rays: np.ndarray,
    firsts: np.ndarray,
    lasts: np.ndarray,
    bands: np.ndarray,
    backgrounds: np.ndarray,
    full_scale: float,
    lowest: float,
    blurs: np.ndarray,
    response: tuple[np.ndarray, np.ndarray],
    edges: np.ndarray,
) -> tuple[float, np.ndarray, int, float]:
    """The spot's log amplitude that fits ``rays`` best (:func:`fit_clipped_edges`' search from ``lowest``), the
    grid's costs, its best node and the cost's curvature there (per log amplitude squared)."""
    # Coarse to fine: every _COARSE_STRIDE-th amplitude, then every amplitude about the best of those, widened
    # while the best lies at the fine search's end.
    costs = np.full(_AMPLITUDE_GRID, np.inf)
    for j in range(0, _AMPLITUDE_GRID, _COARSE_STRIDE):
        costs[j] = _profile_cost(
            shape, offset, angles, sample_radii, profiles, crossings, rays, firsts, lasts, bands,
            backgrounds, full_scale, lowest + _AMPLITUDE_STEP * j, blurs, response, edges,
        )  # fmt: skip
    coarse = int(np.argmin(costs))
    low, high = max(coarse - _COARSE_STRIDE // 2, 0), min(coarse + _COARSE_STRIDE // 2, _AMPLITUDE_GRID - 1)
    j = -1
    while True:
        for node in range(low, high + 1):
            if not np.isfinite(costs[node]):
                costs[node] = _profile_cost(
                    shape, offset, angles, sample_radii, profiles, crossings, rays, firsts, lasts, bands,
                    backgrounds, full_scale, lowest + _AMPLITUDE_STEP * node, blurs, response, edges,
                )  # fmt: skip
        j = int(np.argmin(costs))
        if j == low and low > 0:
            low -= 1
        elif j == high and high < _AMPLITUDE_GRID - 1:
            high += 1
        else:
            break
    # A parabola through the best node and its neighbours; at the grid's ends, the node itself (a clipped plateau is
    # at full scale or over), its curvature through the next two.
    log_amplitude = lowest + _AMPLITUDE_STEP * j
    middle = min(max(j, 1), _AMPLITUDE_GRID - 2)
    below, centre, above = costs[middle - 1], costs[middle], costs[middle + 1]
    curvature = (below - 2.0 * centre + above) / _AMPLITUDE_STEP**2
    if not np.isfinite(curvature):
        curvature = 0.0
    if middle == j and curvature > 0.0:
        where = 0.5 * (below - above) / (below - 2.0 * centre + above)
        log_amplitude += min(max(where, -0.5), 0.5) * _AMPLITUDE_STEP
    return log_amplitude, costs, j, curvature


@njit(cache=True)
def _blur_move(
    shape: tuple[int, int],
    offset: np.ndarray,
    angles: np.ndarray,
    sample_radii: np.ndarray,
    profiles: np.ndarray,
    crossings: np.ndarray,
    rays: np.ndarray,
    firsts: np.ndarray,
    lasts: np.ndarray,
    bands: np.ndarray,
    backgrounds: np.ndarray,
    full_scale: float,
    lowest: float,
    blurs: np.ndarray,
    response: tuple[np.ndarray, np.ndarray],
    edges: np.ndarray,
    moved: np.ndarray,
) -> float:
    """How far ``rays``' edges move together from ``edges`` when the spot is read with ``blurs`` instead (its
    amplitude searched again), pixels; ``moved`` takes the moved edges."""
    other_amplitude = _search_amplitude(
        shape, offset, angles, sample_radii, profiles, crossings, rays, firsts, lasts, bands, backgrounds,
        full_scale, lowest, blurs, response, moved,
    )[0]  # fmt: skip
    _profile_cost(
        shape, offset, angles, sample_radii, profiles, crossings, rays, firsts, lasts, bands, backgrounds,
        full_scale, other_amplitude, blurs, response, moved,
    )  # fmt: skip
    return _mean_move(edges, moved, rays)


@njit(cache=True)
def _mean_move(edges: np.ndarray, moved: np.ndarray, rays: np.ndarray) -> float:
    """The mean of ``moved - edges`` over ``rays``, pixels."""
    total = 0.0
    for r in rays:
        total += moved[r] - edges[r]
    return total / len(rays)
