"""Figure 6.16 of the thesis: the spot at (0, 0, 8) mm, straight down, at each power, and the criterion of the
thesis's exposure (the exposure at which that spot is white at 1 W; docs/methods.md, "The thesis's exposure").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from spotnav.experiments.report import Options
from spotnav.experiments.runner import FrameJob, render_frame
from spotnav.experiments.scenes import thesis_world
from spotnav.optics.camera import camera_depth_mm, project_points
from spotnav.optics.render import Renderer
from spotnav.optics.response import decode_values
from spotnav.setup.geometry import InstrumentPose
from spotnav.setup.microscope import Camera

__all__ = ["GALLERY_POSE", "gallery_centre", "power_gallery", "saturating_exposure_stops"]

GALLERY_POSE = InstrumentPose(np.array([0.0, 0.0, 8.0]), np.array([0.0, 0.0, -1.0]))  # Figure 6.16


def power_gallery(options: Options, powers_w: Sequence[float], exposure_stops: float) -> dict[str, np.ndarray]:
    """Crops of a spot at (0, 0, 8) mm, straight down, at each of ``powers_w`` (Figure 6.16), by ``"1 W"``."""
    worlds = [thesis_world(options.size_px, 1, p, exposure_stops=exposure_stops) for p in powers_w]
    frames = options.runner.map(render_frame, [FrameJob(w, GALLERY_POSE, 5, ()) for w in worlds], "power gallery")
    camera = worlds[0].camera
    u, v = project_points(camera, np.zeros(3))
    half = round(1.8 * camera.focal_px / float(camera_depth_mm(camera, np.zeros(3))))  # the spot's radius: 1.27 mm
    return {
        f"{p:g} W": frame[max(int(v) - half, 0) : int(v) + half, max(int(u) - half, 0) : int(u) + half].copy()
        for p, frame in zip(powers_w, frames, strict=True)
    }


def saturating_exposure_stops(size_px: int) -> float:
    """The exposure at which the Figure 6.16 spot is white at 1 W: the thesis's exposure's criterion.

    Renders the spot at (0, 0, 8) mm, straight down, at 1 W and the default exposure,
    without noise, and returns the stops that bring the median of the darkest channel's
    linear light over the spot's centre (a disc of 0.5 mm on the retina) to full scale.
    """
    world = thesis_world(size_px, 1)
    world = replace(world, render=replace(world.render, full_well_e=0.0, bit_depth=16))
    frame = Renderer(world).render(GALLERY_POSE, seed=5)
    light = decode_values(frame[gallery_centre(world.camera)] / 65535.0, world.camera.pixel_response)
    return float(-np.log2(np.median(light.min(axis=1))))


def gallery_centre(camera: Camera) -> np.ndarray:
    """The pixels (height, width) bool of the Figure 6.16 spot's centre: a disc of 0.5 mm about the pole."""
    centre = project_points(camera, np.zeros(3))
    radius_px = 0.5 * camera.focal_px / float(camera_depth_mm(camera, np.zeros(3)))
    rows, cols = np.indices((camera.height_px, camera.width_px))
    inside: np.ndarray = np.hypot(cols - centre[0], rows - centre[1]) <= radius_px
    return inside
