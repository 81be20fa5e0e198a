"""ms per frame of each stage (see ``spotnav bench`` for medians and 99th percentiles over a path)."""

from __future__ import annotations

from typing import Any

import numpy as np

from spotnav.app.track import track_frame
from spotnav.optics.render import Renderer
from spotnav.pose.localize import localize
from spotnav.pose.precise import localize_precise
from spotnav.setup.config import Setup
from spotnav.setup.paths import helix_tips, poses_through_insertion

Scene = tuple[Setup, Renderer, list[np.ndarray]]


def test_render(benchmark: Any, scene: Scene) -> None:
    setup, renderer, _ = scene
    pose = poses_through_insertion(helix_tips(300)[:1], setup.instrument.insertion_in_eye)[0]
    assert benchmark(renderer.render, pose).shape[:2] == (setup.camera.height_px, setup.camera.width_px)


def test_thesis_full_frame(benchmark: Any, scene: Scene) -> None:
    setup, _, frames = scene
    assert benchmark(localize, frames[1], setup, "thesis").ok


def test_precise_full_frame(benchmark: Any, scene: Scene) -> None:
    setup, _, frames = scene
    assert benchmark(localize, frames[1], setup, "precise").ok


def test_tracking(benchmark: Any, scene: Scene) -> None:
    setup, _, frames = scene
    previous = localize_precise(frames[0], setup)
    assert benchmark(track_frame, frames[1], setup, previous).ok
