"""Procedural retina albedo: vessels, optic disc, fovea and mottling (seeded).

The texture is a square RGB image over eye-frame ``x, y`` in
``[-TEXTURE_HALF_WIDTH_MM, TEXTURE_HALF_WIDTH_MM]``, mapped on the retina by
planar projection along ``z``. Values are linear albedo in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

__all__ = ["TEXTURE_HALF_WIDTH_MM", "AlbedoTexture", "make_texture", "sample_albedo"]

TEXTURE_HALF_WIDTH_MM = 10.0
_TEXELS = 4096
_FUNDUS_RGB = np.array([0.78, 0.34, 0.15], dtype=np.float32)
_DISC_RGB = np.array([0.95, 0.78, 0.52], dtype=np.float32)
_OPTIC_DISC_MM = (-4.6, 0.5)
_OPTIC_DISC_RADIUS_MM = 0.85
_FOVEA_MM = (0.4, -0.3)


@dataclass(frozen=True)
class AlbedoTexture:
    """A texture image and its placement.

    Attributes
    ----------
    rgb : ndarray, shape (N, N, 3), float32
        Linear albedo; row 0 is ``y = +half_width_mm``, column 0 is ``x = -half_width_mm``.
    half_width_mm : float
    """

    rgb: np.ndarray
    half_width_mm: float

    @property
    def texels_per_mm(self) -> float:
        """Texture resolution."""
        texels: int = self.rgb.shape[1]
        return texels / (2.0 * self.half_width_mm)


def _smooth_noise(rng: np.random.Generator, cells: int, size: int) -> np.ndarray:
    """Zero-mean, unit-ish band-limited noise of ``cells`` blobs across, shape (size, size)."""
    coarse = rng.standard_normal((cells, cells)).astype(np.float32)
    return cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC)


def _vessel_map(rng: np.random.Generator, size: int) -> np.ndarray:
    """Vessel coverage in [0, 1]: random-walk trees leaving the optic disc."""
    canvas = np.zeros((size, size), dtype=np.float32)
    scale = size / (2.0 * TEXTURE_HALF_WIDTH_MM)
    shift = 16  # fixed-point bits for sub-texel polylines

    def to_texels(x: float, y: float) -> tuple[float, float]:
        return ((x + TEXTURE_HALF_WIDTH_MM) * scale, (TEXTURE_HALF_WIDTH_MM - y) * scale)

    stack: list[tuple[float, float, float, float, int]] = []
    for heading in np.linspace(0.0, 2.0 * np.pi, 6, endpoint=False) + rng.uniform(0, 0.6):
        x = _OPTIC_DISC_MM[0] + 0.3 * np.cos(heading)
        y = _OPTIC_DISC_MM[1] + 0.3 * np.sin(heading)
        stack.append((x, y, float(heading), 0.13 * rng.uniform(0.7, 1.1), 0))
    step = 0.06
    while stack:
        x, y, heading, width, depth = stack.pop()
        points = [to_texels(x, y)]
        for _ in range(int(14.0 / (1 + depth) / step)):
            # Arcades bend around the fovea; the rest wanders.
            to_fovea = np.arctan2(_FOVEA_MM[1] - y, _FOVEA_MM[0] - x)
            bend = 0.02 * np.sin(to_fovea - heading) if depth == 0 else 0.0
            heading += rng.normal(0.0, 0.06) + bend
            x += step * np.cos(heading)
            y += step * np.sin(heading)
            points.append(to_texels(x, y))
            if abs(x) > TEXTURE_HALF_WIDTH_MM or abs(y) > TEXTURE_HALF_WIDTH_MM:
                break
            if depth < 3 and width > 0.03 and rng.random() < 0.012:
                side = rng.choice([-1.0, 1.0])
                stack.append((x, y, heading + side * rng.uniform(0.4, 0.9), width * 0.7, depth + 1))
                width *= 0.9
        thickness = max(1, round(width * scale))
        fixed = np.round(np.array(points) * (1 << shift)).astype(np.int32)
        cv2.polylines(canvas, [fixed], False, 1.0, thickness, cv2.LINE_AA, shift)
    return cv2.GaussianBlur(canvas, (0, 0), 1.0)


@lru_cache(maxsize=4)
def make_texture(kind: str = "retina", seed: int = 0) -> AlbedoTexture:
    """Build (and cache) the albedo texture.

    Parameters
    ----------
    kind : {"retina", "flat"}
        ``"flat"`` is the fundus colour everywhere.
    seed : int
        Seed of the vessels and mottling.
    """
    size = _TEXELS
    if kind == "flat":
        rgb: np.ndarray = np.broadcast_to(_FUNDUS_RGB, (size, size, 3)).copy()
    elif kind == "retina":
        rng = np.random.default_rng(seed)
        # Smooth features at a coarse grid, then upsampled; vessels at full size.
        coarse = 1024
        coords = (np.arange(coarse, dtype=np.float32) + 0.5) / coarse * 2 * TEXTURE_HALF_WIDTH_MM
        x, y = np.meshgrid(coords - TEXTURE_HALF_WIDTH_MM, TEXTURE_HALF_WIDTH_MM - coords)
        shade = 1.0 + 0.12 * _smooth_noise(rng, 12, coarse)
        fovea = 1.0 - 0.35 * np.exp(-((x - _FOVEA_MM[0]) ** 2 + (y - _FOVEA_MM[1]) ** 2) / (2 * 0.7**2))
        small = _FUNDUS_RGB * (shade * fovea)[..., None]
        disc_r = np.hypot(x - _OPTIC_DISC_MM[0], y - _OPTIC_DISC_MM[1])
        disc = np.clip((_OPTIC_DISC_RADIUS_MM - disc_r) / 0.08 + 0.5, 0.0, 1.0)[..., None]
        small = (small * (1.0 - disc) + _DISC_RGB * disc).astype(np.float32)
        # float32 as ``small`` is (no copy): cv2's stubs type a resize's depth as any
        rgb = cv2.resize(small, (size, size), interpolation=cv2.INTER_LINEAR).astype(np.float32, copy=False)
        mottle = 1.0 + 0.04 * _smooth_noise(rng, 300, size)
        vessels = _vessel_map(rng, size)
        for channel, contrast in enumerate((0.3, 0.5, 0.5)):
            rgb[..., channel] *= mottle * (1.0 - contrast * vessels)
    else:
        raise ValueError(f"texture kind must be 'retina' or 'flat', got {kind!r}")
    rgb = np.clip(rgb, 0.0, 1.0, out=rgb)
    rgb.setflags(write=False)
    return AlbedoTexture(rgb=rgb, half_width_mm=TEXTURE_HALF_WIDTH_MM)


def sample_albedo(texture: AlbedoTexture, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """Bilinear albedo at eye-frame ``(x, y)``.

    Parameters
    ----------
    texture : AlbedoTexture
    x_mm, y_mm : ndarray, shape (H, W)
        Surface coordinates; NaN gives black.

    Returns
    -------
    ndarray, shape (H, W, 3), float32
    """
    scale = texture.texels_per_mm
    outside = -1e6  # remap gives the border value there
    map_x = np.nan_to_num((np.asarray(x_mm) + texture.half_width_mm) * scale - 0.5, nan=outside)
    map_y = np.nan_to_num((texture.half_width_mm - np.asarray(y_mm)) * scale - 0.5, nan=outside)
    map_x, map_y = map_x.astype(np.float32), map_y.astype(np.float32)
    return cv2.remap(
        texture.rgb, map_x, map_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0
    )
