"""A path by its name or its CSV file: the tips and poses that ``render --path``, ``sweep`` and the studies move
the instrument along (the named paths are :mod:`spotnav.setup.paths`'s; a CSV file is read here)."""

from __future__ import annotations

import numpy as np

from spotnav.errors import InputError
from spotnav.files.poses import read_path_csv
from spotnav.setup.geometry import InstrumentPose
from spotnav.setup.paths import helix_tips, poses_through_insertion, resample_polyline, square_tips

__all__ = ["path_poses", "path_tips"]


def path_tips(path: str, frames: int, *, resample: bool = True) -> np.ndarray:
    """A path's ``frames`` tips, shape (frames, 3), mm.

    Parameters
    ----------
    path : str
        ``square`` (:func:`square_tips`), ``helix`` (:func:`helix_tips`) or a CSV file of tips
        (:func:`spotnav.files.poses.read_path_csv`).
    frames : int
    resample : bool
        A CSV file's tips: resampled evenly by arc length along them (:func:`resample_polyline`), or else its
        first ``frames`` tips as they are.

    Raises
    ------
    InputError
        If the CSV file cannot be read, or, not resampled, holds fewer than ``frames`` tips.
    """
    if path == "square":
        return square_tips(frames)
    if path == "helix":
        return helix_tips(frames)
    tips = read_path_csv(path)
    if resample:
        return resample_polyline(tips, frames)
    if len(tips) < frames:
        raise InputError(f"{path} has {len(tips)} tips, fewer than the {frames} frames asked for")
    return tips[:frames]


def path_poses(path: str, frames: int, insertion_in_eye: np.ndarray, *, resample: bool = True) -> list[InstrumentPose]:
    """A path's ``frames`` poses (:func:`path_tips`), each axis from the insertion point (the thesis's RCM)."""
    return poses_through_insertion(path_tips(path, frames, resample=resample), insertion_in_eye)
