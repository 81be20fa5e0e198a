"""Shared fixtures: small setups and cached renderers."""

from __future__ import annotations

from dataclasses import replace

import pytest

from spotnav.config import Camera, Light, Render, Setup
from spotnav.render import Renderer


def small_setup(size_px: int = 512, *, blend: float = 0.0, **render: object) -> Setup:
    """The thesis setup at a smaller image size (same field of view)."""
    base = Setup(camera=Camera(width_px=size_px, height_px=size_px), light=Light(power_w=1.0, blend=blend))
    return replace(base, render=replace(Render(), **render)) if render else base


@pytest.fixture(scope="session")
def renderer_512() -> Renderer:
    """Sharp-edged, textured, noisy 512 px renderer."""
    return Renderer(small_setup(512))


@pytest.fixture(scope="session")
def renderer_2048() -> Renderer:
    """Sharp-edged, textured, noisy 2048 px renderer."""
    return Renderer(small_setup(2048))
