"""Shared fixtures: small setups and cached renderers."""

from __future__ import annotations

import time
from collections.abc import Iterator
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


class SteppedClock:
    """A clock that moves only when slept on: a replay's pace as a schedule, whatever the machine's load."""

    def __init__(self) -> None:
        self.now = time.perf_counter()  # never ahead of the real clock: a latency taken against it stays >= 0
        self.slept: list[float] = []

    def perf_counter(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.now += seconds


@pytest.fixture
def replay_clock(monkeypatch: pytest.MonkeyPatch) -> Iterator[SteppedClock]:
    """A :class:`SteppedClock` in place of the clock by which a recording's replay waits for its frames' times."""
    from spotnav.files import recording

    clock = SteppedClock()
    monkeypatch.setattr(recording, "time", clock)
    yield clock
