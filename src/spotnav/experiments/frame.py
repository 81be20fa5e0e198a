"""One frame rendered, localized and timed: the step that every experiment's loop repeats.

:func:`run_timed_frame` renders a pose with its noise seed and localizes the image with each of several
(setup, method) pairs, timing each stage. The runner's jobs (:func:`spotnav.experiments.runner.run_frame`) and
the sweep's chunks go through it; the speed benchmark and the profiler, which put tracking or the profiler
between the two stages, use its halves, :func:`render_timed` and :func:`localize_timed`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from spotnav.optics.render import Renderer
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.localize import localize
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose

__all__ = ["TimedFrame", "localize_timed", "render_timed", "run_timed_frame"]


@dataclass(frozen=True)
class TimedFrame:
    """A rendered frame and its estimates, each stage's wall time beside it.

    Attributes
    ----------
    image : ndarray
        The rendered frame.
    render_ms : float
    estimates : tuple of PoseEstimate
        One per localizer, in order.
    localize_ms : tuple of float
        Each estimate's time.
    """

    image: np.ndarray
    render_ms: float
    estimates: tuple[PoseEstimate, ...]
    localize_ms: tuple[float, ...]


def render_timed(renderer: Renderer, pose: InstrumentPose, seed: int) -> tuple[np.ndarray, float]:
    """``pose`` rendered with noise ``seed``, and the rendering's time, ms."""
    start = time.perf_counter()
    image = renderer.render(pose, seed=seed)
    return image, 1000 * (time.perf_counter() - start)


def localize_timed(image: np.ndarray, setup: Setup, method: str) -> tuple[PoseEstimate, float]:
    """``image`` localized with ``setup`` by ``method`` (:data:`spotnav.pose.localize.METHODS`), and its time, ms."""
    start = time.perf_counter()
    estimate = localize(image, setup, method)
    return estimate, 1000 * (time.perf_counter() - start)


def run_timed_frame(
    renderer: Renderer, pose: InstrumentPose, seed: int, localizers: Sequence[tuple[Setup, str]]
) -> TimedFrame:
    """Render ``pose`` with noise ``seed`` and localize the frame with each ``(setup, method)`` of ``localizers``."""
    image, render_ms = render_timed(renderer, pose, seed)
    timed = [localize_timed(image, setup, method) for setup, method in localizers]
    return TimedFrame(image, render_ms, tuple(e for e, _ in timed), tuple(ms for _, ms in timed))
