"""Shared fixtures: small setups and cached renderers."""

from __future__ import annotations

from dataclasses import replace

import pytest
from hypothesis import settings

from spotnav.optics.render import Renderer
from spotnav.setup.config import Setup
from spotnav.setup.microscope import Camera
from spotnav.setup.sections import Light, Render
from spotnav.setup.uncertainty import Uncertainty

# No per-example deadline: the first example of a test may compile (or load) Numba kernels, and a
# shared 2-core CI machine's timing varies; the suite's time is kept by CI's own limit.
settings.register_profile("spotnav", deadline=None)
settings.load_profile("spotnav")


def small_setup(size_px: int = 512, *, blend: float = 0.0, **render: object) -> Setup:
    """The thesis setup at a smaller image size (same field of view), its geometry known exactly (a simulation)."""
    base = Setup(
        camera=Camera(width_px=size_px, height_px=size_px),
        light=Light(power_w=1.0, blend=blend),
        uncertainty=Uncertainty.exact(),
    )
    return replace(base, render=replace(Render(), **render)) if render else base


@pytest.fixture(scope="session")
def renderer_512() -> Renderer:
    """Sharp-edged, textured, noisy 512 px renderer."""
    return Renderer(small_setup(512))


@pytest.fixture(scope="session")
def renderer_2048() -> Renderer:
    """Sharp-edged, textured, noisy 2048 px renderer."""
    return Renderer(small_setup(2048))
