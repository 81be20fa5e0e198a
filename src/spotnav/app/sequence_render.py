"""A sequence renderer: ``render --path``'s application, a moving instrument into frames and their truth.

:func:`render_sequence` renders the instrument along a path (square, helix or a
CSV of waypoints), its axis through the insertion point, with hand tremor if
asked, into a folder of PNGs (``truth.csv`` inside) or a video (``FILE.truth.csv``
beside it), and returns where it wrote them. :func:`check_inside` is the check
that every rendered tip lies in the eye.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spotnav.app.paths import path_tips
from spotnav.app.progress import progress
from spotnav.errors import SpotnavError
from spotnav.files.poses import write_truth_csv
from spotnav.files.sequences import SequenceWriter
from spotnav.optics.render import Renderer
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose
from spotnav.setup.paths import tremor_offsets

__all__ = ["RenderedSequence", "check_inside", "render_sequence"]


@dataclass(frozen=True)
class RenderedSequence:
    """A rendered sequence: its frame count, where the frames are and where their truth is."""

    frames: int
    out: Path
    truth: Path


def check_inside(setup: Setup, tip: np.ndarray, name: str) -> None:
    """Raise :class:`SpotnavError` naming ``name`` if ``tip`` (mm, eye frame) lies outside the setup's eye."""
    if not setup.contains_point(tip):
        raise SpotnavError(
            f"{name} {' '.join(f'{v:g}' for v in tip)} lies outside the eye "
            f"(sphere of radius {setup.eye.radius_mm:g} mm centred at (0, 0, {setup.eye.radius_mm:g}))"
        )


def render_sequence(
    setup: Setup, path: str, out: str | Path, *, frames: int, fps: float, tremor_mm: float, seed: int
) -> RenderedSequence:
    """Render ``frames`` frames along ``path`` into ``out``, frame ``i`` with the sensor noise seed ``seed + i``.

    Parameters
    ----------
    setup : Setup
    path : str
        ``square``, ``helix`` or a CSV file of waypoints (x_mm,y_mm,z_mm).
    out : str or Path
        A folder of PNGs, or a video file (``.mkv``: FFV1).
    frames : int
        At least 2.
    fps : float
        Frame rate, for the tremor and the video.
    tremor_mm : float
        Hand tremor, 6-12 Hz, peak per axis, in [0, 1] mm.
    seed : int
        The first frame's sensor noise seed (and the tremor's).

    Raises
    ------
    SpotnavError
        For too few frames, a frame rate or tremor out of range, a path that cannot be read, or a tip outside the eye.
    """
    if frames < 2:
        raise SpotnavError(f"--frames must be at least 2, got {frames}")
    if not (np.isfinite(fps) and fps > 0):
        raise SpotnavError(f"--fps must be a finite number > 0, got {fps}")
    if not (np.isfinite(tremor_mm) and 0 <= tremor_mm <= 1):
        raise SpotnavError(f"--tremor must be in [0, 1] mm, got {tremor_mm}")
    tips = path_tips(path, frames) + tremor_offsets(frames, fps, tremor_mm, seed)
    for tip in tips:
        check_inside(setup, tip, "a path's tip")
    renderer = Renderer(setup)
    out = Path(out)
    truth = []
    with SequenceWriter(out, fps) as writer:
        for index, tip in enumerate(progress(tips, desc="render", unit="frame")):
            pose = InstrumentPose.through_insertion(tip, setup.instrument.insertion_in_eye)
            truth.append((index, writer.write(index, renderer.render(pose, seed=seed + index)), pose))
    truth_path = out.with_suffix(".truth.csv") if writer.video else out / "truth.csv"  # each output its own
    write_truth_csv(truth_path, truth)
    return RenderedSequence(len(tips), out, truth_path)
