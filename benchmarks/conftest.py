"""Benchmarks (pytest-benchmark): ``make bench``; ``make test`` runs each once at a small size.

Sizes come from ``SPOTNAV_BENCH_SIZES`` (comma-separated px, default 1024,2048,5000).
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from spotnav.experiments.scenes import thesis_world, with_true_edge
from spotnav.optics.render import Renderer
from spotnav.setup.config import Setup
from spotnav.setup.paths import helix_tips, poses_through_insertion

SIZES = [int(s) for s in os.environ.get("SPOTNAV_BENCH_SIZES", "1024,2048,5000").split(",")]


@pytest.fixture(scope="module", params=SIZES, ids=lambda size: f"{size}px")
def scene(request: pytest.FixtureRequest) -> tuple[Setup, Renderer, list[np.ndarray]]:
    """A setup (known exactly, as the simulation knows it), its renderer and two frames of a 300-frame helix."""
    size = request.param
    setup = with_true_edge(thesis_world(size, beams=1))
    renderer = Renderer(setup)
    poses = poses_through_insertion(helix_tips(300)[:2], setup.instrument.insertion_in_eye)
    return setup, renderer, [renderer.render(pose, seed=i) for i, pose in enumerate(poses)]
