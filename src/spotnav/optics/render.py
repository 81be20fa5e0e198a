"""Built-in physically based renderer: the stand-in for the thesis's Blender scene.

Light model (Blender's conventions): each beam is a spot light emitting like a
point light of power ``P`` (radiant intensity ``P / 4 pi`` W/sr), cut to its cone
with Cycles' soft edge, a smoothstep in cosine space over the outer ``blend``
fraction of the cone. Irradiance falls with the inverse square of distance and
the cosine of incidence on a Lambertian retina with a procedural albedo, plus a
dim ambient term. The camera integrates radiance with an exposure, adds
Poisson-Gaussian sensor noise, clips at full scale and encodes the light by
the camera's response (sRGB, linear or a gamma) or an AgX-like tone curve, in
8 or 16 bits.

The eye and the camera are static: the renderer caches the albedo seen by every
pixel, the ambient image and its noise once per world, and each frame computes
light only inside the spots' bounding box, supersampling the pixels that the
cone's edge crosses.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from spotnav.optics.camera import (
    camera_depth_mm,
    pixel_rays,
    project_points,
    unproject_pixels_to_plane,
    unproject_pixels_to_sphere,
)
from spotnav.optics.defocus import light_blur_px, varying_blur
from spotnav.optics.occlusion import pixels_behind_segment
from spotnav.optics.response import encoding_table
from spotnav.optics.texture import make_texture, sample_albedo
from spotnav.setup.config import Setup
from spotnav.setup.geometry import (
    InstrumentPose,
    beam_axes,
    cone_generators,
    cone_sphere_curve,
    intersect_rays_sphere,
    spot_attenuation,
)
from spotnav.setup.microscope import Camera
from spotnav.setup.sections import Bump
from spotnav.setup.sections import Render as RenderSettings

__all__ = [
    "Renderer",
    "albedo_in_box",
    "bump_height",
    "edge_pixels",
    "exposure_gain",
    "irradiance_at",
    "noise_sigma",
    "output_table",
    "static_images",
]

_ROW_CHUNK = 256
_NEWTON_STEPS = 8
_NOISE_MARGIN = 1 << 20
_NOISE_BANK_SEED = 0x5EED
_BOX_AZIMUTHS = np.linspace(0.0, 2.0 * np.pi, 720, endpoint=False)
_FAULTS_STREAM = 0xFA  # the disturbances' random stream, apart from the noise offset's
_GLINT_PEAK = 4.0  # full scales: a specular highlight saturates
_SHAFT_LINEAR = 0.02  # dark steel in the dim ambient light


def exposure_gain(exposure_stops: float) -> float:
    """Linear pixel value per W/mm^2 of irradiance on a white Lambertian surface.

    At 0 stops, a white surface 5 mm below a 1 W source, facing it, is exactly
    full scale (1.0): irradiance ``1 / (4 pi 25)`` W/mm^2, radiance that over pi.
    """
    gain: float = 100.0 * np.pi * 2.0**exposure_stops
    return gain


def output_table(tone: str, response: str | float, bits: int) -> np.ndarray:
    """Pixel value for linear light quantized to 1/65535, shape (65536,): ``table[round(65535 * light)]``.

    ``tone`` ``"camera"`` encodes by the camera's ``response``; ``"agx"`` by
    the AgX-like tone curve whatever the camera says
    (:func:`spotnav.optics.response.encoding_table`).
    """
    return encoding_table(response if tone == "camera" else "agx", bits)


def bump_height(bumps: tuple[Bump, ...], x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Height of the bumps toward the eye's centre and its gradient at ``(x, y)``.

    Returns
    -------
    height, d_height_dx, d_height_dy : ndarray, shape of ``x``
        mm, and mm per mm.
    """
    height = np.zeros_like(x)
    grad_x = np.zeros_like(x)
    grad_y = np.zeros_like(x)
    for bump in bumps:
        sigma2 = (bump.radius_mm / 2.0) ** 2
        dx, dy = x - bump.x_mm, y - bump.y_mm
        h = bump.height_mm * np.exp(-(dx * dx + dy * dy) / (2.0 * sigma2))
        height += h
        grad_x -= h * dx / sigma2
        grad_y -= h * dy / sigma2
    return height, grad_x, grad_y


def irradiance_at(
    points: np.ndarray,
    normals: np.ndarray,
    tip: np.ndarray,
    axes: np.ndarray,
    power_w: float,
    half_angle: float,
    blend: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Irradiance of the beams on the retina, and each beam's cosine: the light model, written once.

    A spot light of ``power_w`` (radiant intensity ``power_w / 4 pi`` W/sr) cut
    to its cone by Cycles' soft edge (:func:`~spotnav.setup.geometry.spot_attenuation`),
    falling with the inverse square of distance and the cosine of incidence.

    Parameters
    ----------
    points, normals : ndarray, shape (..., 3)
        Retina points (eye frame, mm; NaN where none) and inward unit normals.
    tip : ndarray, shape (3,)
        The cones' apex, eye frame, mm.
    axes : ndarray, shape (beams, 3)
        Unit beam axes.
    power_w : float
        Each beam's power, W.
    half_angle : float
        The cone's half-angle, radians.
    blend : float
        The soft edge's share of the cone, in [0, 1].

    Returns
    -------
    irradiance : ndarray, shape (...)
        W/mm^2 (0 where there is no retina).
    cosines : ndarray, shape (beams, ...)
        Cosine of the angle from each beam's axis.
    """
    to_point = points - tip
    dist2 = np.sum(to_point * to_point, axis=-1)
    direction = to_point / np.sqrt(dist2)[..., None]
    incidence = np.clip(-np.sum(direction * normals, axis=-1), 0.0, None)
    cosines = np.einsum("...k,bk->b...", direction, axes)
    mask = spot_attenuation(cosines, half_angle, blend).sum(axis=0)
    irradiance = np.nan_to_num(power_w / (4.0 * np.pi) * mask * incidence / dist2)
    return irradiance, cosines


def edge_pixels(cosines: np.ndarray, half_angle: float) -> np.ndarray:
    """The pixels that a cone's edge crosses, which the renderer supersamples: within 1.5 pixels of it.

    Parameters
    ----------
    cosines : ndarray, shape (beams, h, w)
        Each beam's cosine at a box of pixels (NaN where there is no retina).
    half_angle : float
        The cone's half-angle, radians.

    Returns
    -------
    ndarray, shape (h, w), bool
    """
    cos_edge = np.cos(half_angle)
    edge = np.zeros(cosines.shape[1:], dtype=bool)
    for cosine in np.nan_to_num(cosines):
        gv, gu = np.gradient(cosine)
        edge |= np.abs(cosine - cos_edge) < 1.5 * (np.abs(gu) + np.abs(gv)) + 1e-12
    return edge


class Renderer:
    """Render camera frames of the setup's world.

    Parameters
    ----------
    setup : Setup
        Uses ``camera``, ``instrument``, ``light``, ``world`` (true radius and
        bumps) and ``render``; ``eye.radius_mm`` only when ``world`` has no radius.
    """

    def __init__(self, setup: Setup) -> None:
        self.setup = setup

    @property
    def albedo(self) -> np.ndarray:
        """Albedo seen by each pixel, shape (H, W, 3), float32 (cached)."""
        return static_images(self.setup.camera, self.setup.true_radius_mm, self.setup.world.surface, self.setup.render)[
            0
        ]

    def surface_points(self, u: np.ndarray, v: np.ndarray, bumps: tuple[Bump, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Retina points and inward unit normals seen by pixels.

        Parameters
        ----------
        u, v : ndarray, shape (...)
            Pixel coordinates.
        bumps : tuple of Bump
            Deformations to include (the world's, or none).

        Returns
        -------
        points, normals : ndarray, shape (..., 3)
            Eye frame, mm; NaN where the ray misses the bowl.
        """
        camera = self.setup.camera
        if self.setup.world.surface == "plane":
            points = unproject_pixels_to_plane(camera, np.stack([u, v], axis=-1))
            return points, np.broadcast_to(np.array([0.0, 0.0, 1.0]), points.shape).copy()
        radius = self.setup.true_radius_mm
        center = np.array([0.0, 0.0, radius])
        origin = camera.center_in_eye
        rays = pixel_rays(camera, np.stack([u, v], axis=-1))
        t = intersect_rays_sphere(origin, rays, center, radius, far=True)
        grad_x = grad_y = np.zeros_like(t)
        if bumps:
            for _ in range(_NEWTON_STEPS):  # |P - c| + h(x, y) - R = 0 along the ray
                points = origin + t[..., None] * rays
                radial = points - center
                dist = np.linalg.norm(radial, axis=-1)
                height, grad_x, grad_y = bump_height(bumps, points[..., 0], points[..., 1])
                slope = np.sum(rays * radial, axis=-1) / dist + grad_x * rays[..., 0] + grad_y * rays[..., 1]
                t = t - (dist + height - radius) / slope
        points = origin + t[..., None] * rays
        radial = (points - center) / radius
        if bumps:
            _, grad_x, grad_y = bump_height(bumps, points[..., 0], points[..., 1])
            radial = radial / np.linalg.norm(radial, axis=-1, keepdims=True)
        outward = radial + np.stack([grad_x, grad_y, np.zeros_like(grad_x)], axis=-1)
        normals = -outward / np.linalg.norm(outward, axis=-1, keepdims=True)
        missed = ~(points[..., 2] <= radius + 1e-9)
        points[missed] = np.nan
        return points, normals

    def spot_box(self, tip: np.ndarray, axes: np.ndarray) -> tuple[int, int, int, int] | None:
        """Pixel box ``(u0, v0, u1, v1)`` (exclusive ends) holding every lit pixel."""
        setup = self.setup
        half_angle = setup.instrument.beam_half_angle
        if setup.world.surface == "plane":
            rays = np.concatenate([cone_generators(axis, half_angle, _BOX_AZIMUTHS) for axis in axes])
            if np.any(rays[:, 2] >= -1e-9):  # a generator never meets the plane: the spot is unbounded
                return 0, 0, setup.camera.width_px, setup.camera.height_px
            points = tip + (-tip[2] / rays[:, 2])[:, None] * rays
        else:
            radius = setup.true_radius_mm
            center = np.array([0.0, 0.0, radius])
            points = np.concatenate([cone_sphere_curve(tip, axis, half_angle, center, radius, 720) for axis in axes])
            points = points[np.isfinite(points[:, 2]) & (points[:, 2] <= radius)]
        if len(points) == 0:
            return None
        pixels = project_points(setup.camera, points)
        pad = 4 + self._px_per_mm * max((abs(b.height_mm) for b in setup.world.bumps), default=0.0)
        u0 = max(int(np.floor(pixels[:, 0].min() - pad)), 0)
        v0 = max(int(np.floor(pixels[:, 1].min() - pad)), 0)
        u1 = min(int(np.ceil(pixels[:, 0].max() + pad)) + 1, setup.camera.width_px)
        v1 = min(int(np.ceil(pixels[:, 1].max() + pad)) + 1, setup.camera.height_px)
        if u0 >= u1 or v0 >= v1:
            return None
        # At least 2 px a side, for the edge's gradient (a spot that only grazes the image's border).
        u0, v0 = min(u0, setup.camera.width_px - 2), min(v0, setup.camera.height_px - 2)
        return u0, v0, max(u1, u0 + 2), max(v1, v0 + 2)

    def _irradiance(
        self, u: np.ndarray, v: np.ndarray, tip: np.ndarray, axes: np.ndarray, power_w: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Irradiance (W/mm^2) at the retina seen by pixels, and each beam's cos(angle).

        Returns arrays of shape ``u.shape`` and ``(beams,) + u.shape``.
        """
        points, normals = self.surface_points(u, v, self.setup.world.bumps)
        return irradiance_at(
            points, normals, tip, axes, power_w, self.setup.instrument.beam_half_angle, self.setup.light.blend
        )

    def irradiance_image(
        self, pose: InstrumentPose, power_w: float | None = None
    ) -> tuple[np.ndarray, tuple[int, int, int, int]] | None:
        """Pixel-averaged irradiance inside the spots' box.

        Returns
        -------
        irradiance : ndarray, shape (v1 - v0, u1 - u0)
            W/mm^2, averaged over each pixel's footprint where the edge crosses it.
        box : tuple of int
            ``(u0, v0, u1, v1)``, exclusive ends.

        ``None`` when no light reaches the visible retina.
        """
        power = self.setup.light.power_w if power_w is None else power_w
        axes = beam_axes(pose.axis, self.setup.instrument.beam_count, self.setup.instrument.beam_tilt)
        box = self.spot_box(pose.tip_in_eye, axes)
        if box is None or power == 0.0:
            return None
        u0, v0, u1, v1 = box
        u, v = np.meshgrid(np.arange(u0, u1, dtype=float), np.arange(v0, v1, dtype=float))
        irradiance, cosines = self._irradiance(u, v, pose.tip_in_eye, axes, power)
        edge = edge_pixels(cosines, self.setup.instrument.beam_half_angle)
        n = self.setup.render.supersampling
        if n > 1 and edge.any():
            offsets = (np.arange(n) + 0.5) / n - 0.5
            du, dv = (o.ravel() for o in np.meshgrid(offsets, offsets))
            su = u[edge][:, None] + du[None, :]
            sv = v[edge][:, None] + dv[None, :]
            sub, _ = self._irradiance(su, sv, pose.tip_in_eye, axes, power)
            irradiance[edge] = sub.mean(axis=1)
        return irradiance, box

    def render(self, pose: InstrumentPose, *, seed: int = 0, power_w: float | None = None) -> np.ndarray:
        """Render one RGB frame, 8 or 16 bits (``render.bit_depth``), encoded as ``render.tone`` says.

        Sensor noise is Gaussian with the Poisson variance of the signal plus the
        read noise. Its standard normals are read from a bank of independent
        draws at a seeded random offset: every frame's noise is white and
        reproducible, without drawing a new normal per pixel and channel. The
        setup's ``faults`` add their disturbances, placed by the same seed.

        Parameters
        ----------
        pose : InstrumentPose
            True tip and instrument axis in the eye frame.
        seed : int
            Seed of the sensor noise and the disturbances (frames are reproducible).
        power_w : float, optional
            Overrides ``light.power_w``.

        Returns
        -------
        ndarray, shape (height_px, width_px, 3), uint8 or uint16
            RGB.

        Raises
        ------
        ValueError
            If the tip lies outside the (true) eye.
        """
        radius = self.setup.true_radius_mm
        if self.setup.world.surface == "sphere" and np.linalg.norm(pose.tip_in_eye - [0.0, 0.0, radius]) >= radius:
            tip = ", ".join(f"{v:g}" for v in pose.tip_in_eye)
            raise ValueError(f"the tip ({tip}) mm lies outside the eye (radius {radius:g} mm about (0, 0, {radius:g}))")
        cfg = self.setup.render
        camera = self.setup.camera
        albedo, background, sigma, bank = static_images(
            camera, self.setup.true_radius_mm, self.setup.world.surface, cfg
        )
        patches = self._patches(pose, seed, power_w, albedo, background)
        table = output_table(cfg.tone, camera.pixel_response, cfg.bit_depth)
        noisy = cfg.full_well_e > 0
        if noisy:
            offset = int(np.random.default_rng(seed).integers(0, _NOISE_MARGIN))
            noise = bank[offset : offset + background.size].reshape(background.shape)
        out = np.empty((camera.height_px, camera.width_px, 3), dtype=table.dtype)
        scratch = np.empty((_ROW_CHUNK, camera.width_px, 3), dtype=np.float32)
        for r0 in range(0, camera.height_px, _ROW_CHUNK):
            r1 = min(r0 + _ROW_CHUNK, camera.height_px)
            linear = background[r0:r1].copy()
            chunk_sigma, own_sigma = sigma[r0:r1], False
            for patch in patches:
                a, b = max(r0, patch.v0), min(r1, patch.v0 + len(patch.linear))
                if a >= b:
                    continue
                region = linear[a - r0 : b - r0, patch.u0 : patch.u0 + patch.linear.shape[1]]
                source = patch.linear[a - patch.v0 : b - patch.v0]
                if patch.hides is None:
                    region += source
                else:
                    np.copyto(region, source, where=patch.hides[a - patch.v0 : b - patch.v0, :, None])
                if noisy:
                    if not own_sigma:
                        chunk_sigma, own_sigma = chunk_sigma.copy(), True
                    chunk_sigma[a - r0 : b - r0, patch.u0 : patch.u0 + patch.linear.shape[1]] = noise_sigma(
                        region, cfg.full_well_e, cfg.read_noise_e
                    )
            if noisy:
                linear += np.multiply(chunk_sigma, noise[r0:r1], out=scratch[: r1 - r0])
            np.clip(linear, 0.0, 1.0, out=linear)
            linear *= np.float32(65535.0)
            linear += np.float32(0.5)
            out[r0:r1] = table[linear.astype(np.uint16)]
        if self.setup.faults.frame_blur_px > 0:
            out = cv2.GaussianBlur(out, (0, 0), self.setup.faults.frame_blur_px)
        return out

    def _patches(
        self, pose: InstrumentPose, seed: int, power_w: float | None, albedo: np.ndarray, background: np.ndarray
    ) -> list[_Patch]:
        """What each frame adds to the static background: the spots, then the faults' disturbances, in order."""
        faults = self.setup.faults
        rng = np.random.default_rng([seed, _FAULTS_STREAM])
        more = np.random.default_rng([seed, _FAULTS_STREAM, 1])  # the later disturbances' own stream
        patches: list[_Patch | None] = []
        lit = self.irradiance_image(pose, power_w)
        if lit is not None:
            irradiance, (u0, v0, u1, v1) = lit
            light = albedo[v0:v1, u0:u1] * (exposure_gain(self.setup.render.exposure_stops) * irradiance)[
                ..., None
            ].astype(np.float32)
            if faults.vessels:
                light *= 1.0 - faults.vessel_contrast * self._vessel_mask(light.shape[:2], faults.vessels, rng)
            if faults.dark_patch > 0:  # darker albedo: under the spot's light and the ambient light alike
                darker = faults.dark_patch * self._edge_patch_mask(light.shape[:2], more)
                light *= 1.0 - darker
                patches.append(_Patch(u0, v0, -darker * background[v0:v1, u0:u1]))
            sharp = _Patch(u0, v0, light)
            spot = self._blurred(sharp, faults.motion_blur_px, rng) if faults.motion_blur_px > 0 else sharp
            lens = faults.defocus_px > 0 or self.setup.camera.lens_aperture_mm > 0
            if lens and spot is not None:  # a blurred patch is clipped to the image: maybe None
                spot = self._defocused(spot, faults.defocus_px)
            patches.append(spot)
            centre = np.array([(u0 + u1) / 2.0, (v0 + v1) / 2.0])
            size = np.array([u1 - u0, v1 - v0], dtype=float)
            for _ in range(faults.glints):
                where = centre + rng.uniform(-0.6, 0.6, 2) * size
                patches.append(self._blob(where, max(1.0, 0.012 * self._px_per_mm), _GLINT_PEAK))
            if faults.stray_light > 0:
                direction = rng.uniform(0.0, 2.0 * np.pi)
                distance = rng.uniform(0.15, 0.3) * self.setup.camera.width_px
                where = centre + distance * np.array([np.cos(direction), np.sin(direction)])
                patches.append(self._blob(where, 0.04 * self.setup.camera.width_px, faults.stray_light))
        if faults.shaft and self.setup.instrument.shaft_diameter_mm > 0:
            patches.append(self._shaft(pose))
        if faults.glow > 0:
            patches.append(self._glow(faults.glow, albedo, more))
        return [p for p in patches if p is not None]

    @property
    def _px_per_mm(self) -> float:
        """Pixels per mm on the retina near the pole (1 mm above it, the nearest the spots are)."""
        camera = self.setup.camera
        return camera.focal_px / (float(camera_depth_mm(camera, np.zeros(3))) - 1.0)

    def _vessel_mask(self, shape: tuple[int, int], count: int, rng: np.random.Generator) -> np.ndarray:
        """``count`` random dark lines across a box of ``shape``, 0.05-0.1 mm wide: coverage in [0, 1]."""
        height, width = shape
        mask = np.zeros(shape, dtype=np.float32)
        for _ in range(count):
            through = rng.uniform(0.3, 0.7, 2) * (width, height)
            angle = rng.uniform(0.0, np.pi)
            reach = 2.0 * max(width, height) * np.array([np.cos(angle), np.sin(angle)])
            ends = np.round(np.array([through - reach, through + reach]) * 16).astype(np.int32)
            thickness = max(1, round(rng.uniform(0.05, 0.1) * self._px_per_mm))
            cv2.line(mask, tuple(ends[0]), tuple(ends[1]), 1.0, thickness, cv2.LINE_AA, 4)
        return np.minimum(mask, 1.0)[..., None]

    def _blurred(self, patch: _Patch, length_px: float, rng: np.random.Generator) -> _Patch | None:
        """The patch smeared along a random direction over ``length_px`` (grown to hold the smear)."""
        pad = int(np.ceil(length_px / 2.0)) + 1
        grown = cv2.copyMakeBorder(patch.linear, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
        size = 2 * pad + 1
        kernel = np.zeros((size, size), dtype=np.float32)
        angle = rng.uniform(0.0, np.pi)
        half = length_px / 2.0 * np.array([np.cos(angle), np.sin(angle)])
        ends = np.round((pad + np.array([-half, half])) * 16).astype(np.int32)
        cv2.line(kernel, tuple(ends[0]), tuple(ends[1]), 1.0, 1, cv2.LINE_AA, 4)
        blurred = cv2.filter2D(grown, -1, kernel / kernel.sum(), borderType=cv2.BORDER_CONSTANT)
        return self._clipped(_Patch(patch.u0 - pad, patch.v0 - pad, blurred.reshape((*grown.shape[:2], 3))))

    def _edge_patch_mask(self, shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
        """A soft round patch (1 at its centre) on the edge of the spot that fills a box of ``shape``, (h, w, 1)."""
        height, width = shape
        half = 0.5 * min(height, width) - 4.0  # the spot's radius: the box holds it with 4 px to spare
        angle = rng.uniform(0.0, 2.0 * np.pi)
        centre = np.array([width, height]) / 2.0 + half * np.array([np.cos(angle), np.sin(angle)])
        radius = rng.uniform(0.3, 0.6) * half
        v, u = np.mgrid[:height, :width].astype(np.float32)
        distance2 = (u - centre[0]) ** 2 + (v - centre[1]) ** 2
        mask: np.ndarray = np.exp(-2.0 * distance2 / radius**2)[..., None].astype(np.float32)
        return mask

    def _defocused(self, patch: _Patch, sigma_px: float) -> _Patch | None:
        """The patch blurred by a Gaussian of ``sigma_px`` (grown to hold the blur): the light out of focus; with the
        lens's depth of field (``camera.aperture_mm``), each pixel's blur at its retina point in quadrature
        (:func:`spotnav.optics.defocus.light_blur_px`)."""
        camera = self.setup.camera
        if camera.lens_aperture_mm == 0:
            pad = int(np.ceil(4.0 * sigma_px)) + 1
            grown = cv2.copyMakeBorder(patch.linear, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
            blurred = cv2.GaussianBlur(grown, (0, 0), sigma_px, borderType=cv2.BORDER_CONSTANT)
        else:
            inside = self._lens_blur(patch.u0, patch.v0, patch.linear.shape[:2], sigma_px)
            pad = int(np.ceil(4.0 * 1.5 * np.max(inside))) + 1  # the blur grows toward the bowl's rim
            grown = cv2.copyMakeBorder(patch.linear, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
            sigmas = self._lens_blur(patch.u0 - pad, patch.v0 - pad, grown.shape[:2], sigma_px)
            blurred = varying_blur(grown, sigmas)
        return self._clipped(_Patch(patch.u0 - pad, patch.v0 - pad, blurred.reshape((*grown.shape[:2], 3))))

    def _lens_blur(self, u0: int, v0: int, shape: tuple[int, ...], sigma_px: float) -> np.ndarray:
        """Each pixel's light blur in a box at ``(u0, v0)`` of ``shape`` (h, w): the lens's depth of field at its
        retina point and ``sigma_px`` in quadrature, sigma, pixels; off the bowl, the box's largest."""
        v, u = np.mgrid[v0 : v0 + shape[0], u0 : u0 + shape[1]].astype(float)
        points, _ = self.surface_points(u, v, self.setup.world.bumps)
        depth_blur = light_blur_px(self.setup.camera, points)
        sigmas = np.hypot(depth_blur, sigma_px)
        top = np.nanmax(sigmas) if np.isfinite(sigmas).any() else sigma_px
        return np.where(np.isfinite(sigmas), sigmas, top)

    def _glow(self, peak: float, albedo: np.ndarray, rng: np.random.Generator) -> _Patch | None:
        """An endo-illuminator's glow: a broad Gaussian (a third of the frame across), uneven, on the albedo."""
        camera = self.setup.camera
        size = np.array([camera.width_px, camera.height_px], dtype=float)
        sigma = size.min() / 8.0
        centre = size / 2.0 + rng.uniform(-0.25, 0.25, 2) * size
        reach = int(np.ceil(3.0 * sigma))
        u0, v0 = (np.floor(centre) - reach).astype(int)
        v, u = np.mgrid[v0 : v0 + 2 * reach + 1, u0 : u0 + 2 * reach + 1].astype(np.float32)
        uneven = cv2.resize(
            rng.normal(0.0, 0.3, (4, 4)).astype(np.float32), u.shape[::-1], interpolation=cv2.INTER_CUBIC
        )
        glow = peak * np.exp(-((u - centre[0]) ** 2 + (v - centre[1]) ** 2) / (2.0 * sigma**2)) * (1.0 + uneven)
        patch = self._clipped(_Patch(int(u0), int(v0), np.repeat(np.maximum(glow, 0.0)[..., None], 3, axis=2)))
        if patch is None:
            return None
        height, width = patch.linear.shape[:2]
        return _Patch(
            patch.u0, patch.v0, patch.linear * albedo[patch.v0 : patch.v0 + height, patch.u0 : patch.u0 + width]
        )

    def _blob(self, centre_px: np.ndarray, sigma_px: float, peak: float) -> _Patch | None:
        """A round Gaussian light of ``peak`` full scales, grey, centred at ``centre_px``."""
        reach = int(np.ceil(4.0 * sigma_px))
        u0, v0 = int(np.floor(centre_px[0])) - reach, int(np.floor(centre_px[1])) - reach
        u, v = np.meshgrid(np.arange(u0, u0 + 2 * reach + 2), np.arange(v0, v0 + 2 * reach + 2))
        blob = peak * np.exp(-((u - centre_px[0]) ** 2 + (v - centre_px[1]) ** 2) / (2.0 * sigma_px**2))
        return self._clipped(_Patch(u0, v0, np.repeat(blob[..., None], 3, axis=2).astype(np.float32)))

    def _shaft(self, pose: InstrumentPose) -> _Patch | None:
        """The shaft from the tip to the insertion point: dark steel over whatever lies behind it."""
        setup = self.setup
        end = setup.instrument.insertion_in_eye
        radius = setup.instrument.shaft_diameter_mm / 2.0
        ends_px = project_points(setup.camera, np.array([pose.tip_in_eye, end]))
        depth = float(np.min(camera_depth_mm(setup.camera, np.array([pose.tip_in_eye, end]))))
        pad = radius * setup.camera.focal_px / depth + 2
        u0, v0 = np.floor(ends_px.min(axis=0) - pad).astype(int)
        u1, v1 = np.ceil(ends_px.max(axis=0) + pad).astype(int)
        u, v = np.meshgrid(np.arange(u0, u1 + 1, dtype=float), np.arange(v0, v1 + 1, dtype=float))
        hides = pixels_behind_segment(setup.camera, np.stack([u, v], axis=-1), pose.tip_in_eye, end, radius)
        steel = np.full((*hides.shape, 3), _SHAFT_LINEAR, dtype=np.float32)
        return self._clipped(_Patch(int(u0), int(v0), steel, hides))

    def _clipped(self, patch: _Patch) -> _Patch | None:
        """The part of a patch inside the image (None if nothing is)."""
        camera = self.setup.camera
        height, width = patch.linear.shape[:2]
        a, b = max(-patch.u0, 0), max(-patch.v0, 0)
        c, d = min(camera.width_px - patch.u0, width), min(camera.height_px - patch.v0, height)
        if a >= c or b >= d:
            return None
        hides = None if patch.hides is None else patch.hides[b:d, a:c]
        return _Patch(patch.u0 + a, patch.v0 + b, patch.linear[b:d, a:c], hides)


@dataclass(frozen=True)
class _Patch:
    """Linear light ``linear`` (h, w, 3) added at pixel ``(u0, v0)``, or put where ``hides`` (h, w) is true."""

    u0: int
    v0: int
    linear: np.ndarray
    hides: np.ndarray | None = None


def albedo_in_box(
    camera: Camera, radius_mm: float, surface: str, cfg: RenderSettings, box: tuple[int, int, int, int]
) -> np.ndarray:
    """Albedo seen by the pixels of ``box`` ``(u0, v0, u1, v1)`` (exclusive ends), shape (v1 - v0, u1 - u0, 3),
    float32: what :func:`static_images` holds for them, without the whole frame."""
    u0, v0, u1, v1 = box
    pixels = np.stack(np.meshgrid(np.arange(u0, u1, dtype=float), np.arange(v0, v1, dtype=float)), axis=-1)
    if surface == "plane":
        points = unproject_pixels_to_plane(camera, pixels)
    else:
        points = unproject_pixels_to_sphere(camera, pixels, radius_mm)
    albedo: np.ndarray = sample_albedo(make_texture(cfg.texture, cfg.texture_seed), points[..., 0], points[..., 1])
    return albedo.astype(np.float32, copy=False)


@functools.lru_cache(maxsize=1)
def static_images(
    camera: Camera, radius_mm: float, surface: str, cfg: RenderSettings
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What does not change between frames of one world, computed once (the last world is kept).

    Returns
    -------
    albedo, background, sigma : ndarray, shape (H, W, 3), float32
        Albedo seen by each pixel, the ambient-lit linear image and its noise sigma.
    bank : ndarray, shape (H * W * 3 + margin,), float32
        Independent standard normals; each frame reads them at a seeded offset.

    Texture lookups use the sphere: a bump shifts its texture by at most its
    height times the ray's slope (under 0.01 mm here), which is ignored.
    """
    albedo = np.empty((camera.height_px, camera.width_px, 3), dtype=np.float32)
    for r0 in range(0, camera.height_px, _ROW_CHUNK):
        rows = (0, r0, camera.width_px, min(r0 + _ROW_CHUNK, camera.height_px))
        albedo[r0 : rows[3]] = albedo_in_box(camera, radius_mm, surface, cfg, rows)
    background = albedo * np.float32(cfg.ambient)
    sigma = noise_sigma(background, cfg.full_well_e, cfg.read_noise_e)
    size = albedo.size + _NOISE_MARGIN
    bank = np.random.default_rng(_NOISE_BANK_SEED).standard_normal(size, dtype=np.float32)
    return albedo, background, sigma, bank


def noise_sigma(linear: np.ndarray, full_well_e: float, read_noise_e: float) -> np.ndarray:
    """Standard deviation of shot plus read noise for linear pixel values (full scale 1), same shape.

    Poisson shot noise of ``full_well_e`` electrons at full scale, plus Gaussian
    read noise of ``read_noise_e`` electrons; none when ``full_well_e`` is 0.
    """
    if full_well_e <= 0:
        return np.zeros_like(linear)
    variance = np.maximum(linear, 0.0) / np.float32(full_well_e) + np.float32((read_noise_e / full_well_e) ** 2)
    sigma: np.ndarray = np.sqrt(variance)
    return sigma
