"""Instrument paths of the thesis's chapter 6 and the working volume."""

from __future__ import annotations

import numpy as np

from spotnav.geometry import InstrumentPose

__all__ = [
    "HELIX",
    "SQUARE_CORNERS_MM",
    "helix_tips",
    "poses_through_insertion",
    "square_tips",
    "working_volume_tips",
]

SQUARE_CORNERS_MM = np.array([[-2.5, -2.5, 3.0], [2.5, -2.5, 4.0], [2.5, 2.5, 5.0], [-2.5, 2.5, 6.0]])  # Table 6.7
HELIX = {"radius_mm": 2.0, "turns": 2.0, "z_start_mm": 3.0, "z_end_mm": 6.0}  # thesis-notes 8: our choice


def square_tips(count: int) -> np.ndarray:
    """``count`` tips evenly spaced by arc length along P1-P2-P3-P4-P1 (Table 6.7), shape (count, 3).

    The path is closed: the first tip is P1 and the last one stops a step short of it.
    """
    corners = np.vstack([SQUARE_CORNERS_MM, SQUARE_CORNERS_MM[:1]])
    lengths = np.linalg.norm(np.diff(corners, axis=0), axis=1)
    along = np.concatenate([[0.0], np.cumsum(lengths)])
    s = np.linspace(0.0, along[-1], count, endpoint=False)
    return np.column_stack([np.interp(s, along, corners[:, k]) for k in range(3)])


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
