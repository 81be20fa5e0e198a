"""Localize the instrument tip in one camera frame, by a named method.

Methods (:data:`METHODS`): ``thesis`` (the thesis's Algorithms 1 and 2,
:mod:`spotnav.thesis`), ``precise`` (the default: sub-pixel edges and a direct
cone fit with the axis through the insertion point, :mod:`spotnav.precise`)
and ``precise-free`` (the axis fitted too); see ``docs/methods.md``. Every
method returns a :class:`~spotnav.estimate.PoseEstimate`: a pose with status
``ok``, or a status that says why there is none. No method makes up a pose.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np

from spotnav.config import Setup
from spotnav.estimate import PoseEstimate
from spotnav.precise import localize_precise
from spotnav.thesis import localize_thesis

__all__ = ["DEFAULT_METHOD", "METHODS", "localize"]

METHODS: dict[str, Callable[[np.ndarray, Setup], PoseEstimate]] = {
    "precise": localize_precise,
    "precise-free": partial(localize_precise, through_insertion=False),
    "thesis": localize_thesis,
}
DEFAULT_METHOD = "precise"


def localize(image: np.ndarray, setup: Setup, method: str = DEFAULT_METHOD) -> PoseEstimate:
    """Localize the tip with a named method (see :data:`METHODS`).

    Raises
    ------
    ValueError
        For an unknown method.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    return METHODS[method](image, setup)
