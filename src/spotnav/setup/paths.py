"""Instrument paths: the thesis's chapter 6 square and helix, a polyline resampled, hand tremor, the working volume.

Every study, ``spotnav render --path`` and the sweeps turn a path's name (``square``, ``helix`` or a CSV file of
tips) into tips and poses with :func:`spotnav.app.paths.path_tips` and :func:`spotnav.app.paths.path_poses`.
"""

from __future__ import annotations

import numpy as np

from spotnav.errors import InputError
from spotnav.setup.geometry import InstrumentPose

__all__ = [
    "HELIX",
    "SQUARE_CORNERS_MM",
    "helix_tips",
    "poses_through_insertion",
    "resample_polyline",
    "square_tips",
    "tremor_offsets",
    "working_volume_tips",
]

SQUARE_CORNERS_MM = np.array([[-2.5, -2.5, 3.0], [2.5, -2.5, 4.0], [2.5, 2.5, 5.0], [-2.5, 2.5, 6.0]])  # Table 6.7
HELIX = {"radius_mm": 2.0, "turns": 2.0, "z_start_mm": 3.0, "z_end_mm": 6.0}  # thesis-notes 8: our choice


def square_tips(count: int) -> np.ndarray:
    """``count`` tips evenly spaced by arc length along P1-P2-P3-P4-P1 (Table 6.7), shape (count, 3).

    The path is closed: the first tip is P1 and the last one stops a step short of it.
    """
    return resample_polyline(np.vstack([SQUARE_CORNERS_MM, SQUARE_CORNERS_MM[:1]]), count, endpoint=False)


def resample_polyline(points: np.ndarray, count: int, *, endpoint: bool = True) -> np.ndarray:
    """``count`` points evenly spaced by arc length along a polyline, shape (count, 3).

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        The polyline's vertices, N >= 2, not all equal.
    count : int
    endpoint : bool
        Whether the last point is the last vertex (else it stops a step short).
    """
    points = np.asarray(points, dtype=float)
    lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
    along = np.concatenate([[0.0], np.cumsum(lengths)])
    if len(points) < 2 or along[-1] <= 0:
        raise InputError("a path needs at least two distinct points")
    s = np.linspace(0.0, along[-1], count, endpoint=endpoint)
    return np.column_stack([np.interp(s, along, points[:, k]) for k in range(3)])


def tremor_offsets(count: int, fps: float, amplitude_mm: float, seed: int = 0) -> np.ndarray:
    """Physiological hand tremor: per axis, a sine of random frequency in 6-12 Hz and phase, shape (count, 3).

    Parameters
    ----------
    count : int
        Frames.
    fps : float
        Frame rate, frames per second.
    amplitude_mm : float
        Peak amplitude per axis, mm (surgeons' tremor is some 0.05 mm).
    seed : int
    """
    rng = np.random.default_rng(seed)
    frequency_hz = rng.uniform(6.0, 12.0, 3)
    phase = rng.uniform(0.0, 2.0 * np.pi, 3)
    time_s = np.arange(count)[:, None] / fps
    return amplitude_mm * np.sin(2.0 * np.pi * frequency_hz * time_s + phase)


def helix_tips(
    count: int,
    radius_mm: float = HELIX["radius_mm"],
    turns: float = HELIX["turns"],
    z_start_mm: float = HELIX["z_start_mm"],
    z_end_mm: float = HELIX["z_end_mm"],
) -> np.ndarray:
    """``count`` tips on a helix about the z axis, from ``z_start_mm`` to ``z_end_mm``, shape (count, 3)."""
    t = np.linspace(0.0, 1.0, count)
    angle = 2.0 * np.pi * turns * t
    return np.column_stack(
        [radius_mm * np.cos(angle), radius_mm * np.sin(angle), z_start_mm + (z_end_mm - z_start_mm) * t]
    )


def working_volume_tips(count: int, seed: int = 0) -> np.ndarray:
    """Tips drawn uniformly in x, y in [-2.5, 2.5] mm and z in [3, 6] mm, shape (count, 3)."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-2.5, 2.5, count), rng.uniform(-2.5, 2.5, count), rng.uniform(3.0, 6.0, count)])


def poses_through_insertion(tips: np.ndarray, insertion_in_eye: np.ndarray) -> list[InstrumentPose]:
    """One pose per tip, the axis from the insertion point (the thesis's remote centre of motion)."""
    return [InstrumentPose.through_insertion(tip, insertion_in_eye) for tip in np.asarray(tips, dtype=float)]
