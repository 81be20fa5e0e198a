"""The simulated worlds the experiments share: the thesis's setup (Table 6.8), its deformed eye, and how a
localizer knows such a world.

:func:`thesis_world` is Table 6.8's setup at any image size with the default soft edge (``blend = 0.15``,
thesis-notes 8) and the procedural retina; :func:`with_true_edge` is that world as its own localizer knows it
(exactly, with the edge model of its simulated light). Chapter 6's studies and the later ones (calibration,
geometry, mismatch, faults, light, speed) all render in these worlds, with the frame seeds of :data:`PATH_SEEDS`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from spotnav.optics.defocus import spot_light_blur_px
from spotnav.setup.config import Setup
from spotnav.setup.geometry import edge_angle_of_blend
from spotnav.setup.microscope import Camera
from spotnav.setup.paths import helix_tips, poses_through_insertion
from spotnav.setup.sections import Bump, Instrument, Light, Render, World
from spotnav.setup.uncertainty import Uncertainty

__all__ = [
    "BEAMS",
    "PATH_SEEDS",
    "bump_grid",
    "thesis_world",
    "with_lens_blur",
    "with_true_edge",
    "with_uncertainty",
]

PATH_SEEDS = {"square": 0, "helix": 10_000}  # each path's first frame's noise seed
BEAMS = {"1 beam": 1, "3 beams": 3}  # report label -> beam count


def thesis_world(
    size_px: int, beams: int, power_w: float = 1.0, world: World | None = None, exposure_stops: float = 0.0
) -> Setup:
    """Table 6.8's setup at ``size_px``, soft edge, with ``beams`` beams, at ``exposure_stops``."""
    return Setup(
        camera=Camera(width_px=size_px, height_px=size_px),
        instrument=Instrument(beam_count=beams),
        light=Light(power_w=power_w, blend=0.15),
        world=world or World(),
        render=Render(exposure_stops=exposure_stops),
    )


def bump_grid() -> tuple[Bump, ...]:
    """Section 6.7: 15 bumps, radius 0.25 mm, height 0.1 mm, 3 rows by 5 columns over the area of interest."""
    return tuple(Bump(x, y, 0.25, 0.1) for y in (-2.0, 0.0, 2.0) for x in (-3.0, -1.5, 0.0, 1.5, 3.0))


def with_true_edge(world: Setup) -> Setup:
    """The world as its own localizer knows it: exactly, the edge model from its simulated light's blend.

    The simulation knows its light as the thesis's method knows beta, and its
    geometry exactly (``Uncertainty.exact()``); ``spotnav calibrate`` fits the
    edge and the geometry from images where they are not known.
    """
    angle = edge_angle_of_blend(world.instrument.beam_half_angle, world.light.blend)
    instrument = replace(world.instrument, edge_half_angle_deg=float(np.degrees(angle)))
    return replace(world, instrument=instrument, uncertainty=Uncertainty.exact())


def with_uncertainty(setup: Setup, **uncertainty: float) -> Setup:
    """The setup with these ``[uncertainty]`` values (the others as they are)."""
    return replace(setup, uncertainty=replace(setup.uncertainty, **uncertainty))


def with_lens_blur(world: Setup, blur_px: float) -> Setup:
    """The world with a lens (``camera.aperture_mm``, focused at the pole) whose depth of field blurs the light at
    the helix's spots by ``blur_px`` (their median, sigma, pixels; under half of it near the pole, up to 2.6 times
    it at the helix's far side)."""
    poses = poses_through_insertion(helix_tips(_LENS_TIPS), world.instrument.insertion_in_eye)
    per_mm = np.median([spot_light_blur_px(world, p.tip_in_eye, p.axis, 1.0) for p in poses])
    return replace(world, camera=replace(world.camera, aperture_mm=float(blur_px / per_mm)))


_LENS_TIPS = 16  # the helix's tips that set a lens's aperture
