"""The light's edge model as the setup states it: the half-angle at which a spot's edge is drawn.

The image stage reads a spot's edge at this angle (:mod:`spotnav.image.photometry`) and the pose stage fits the
edge cones of this half-angle (:mod:`spotnav.pose.conefit`): a pure function of the setup, shared by both.
"""

from __future__ import annotations

import numpy as np

from spotnav.setup.config import Setup
from spotnav.setup.geometry import edge_angle_of_blend

__all__ = ["DEFAULT_BLEND", "edge_angle"]

DEFAULT_BLEND = 0.15  # Blender's default spot_blend: the edge model when the setup gives none


def edge_angle(setup: Setup) -> float:
    """The edge model's half-angle, radians: ``instrument.edge_half_angle_deg`` or its default.

    The default is the half-light angle of a Cycles spot of the nominal half-angle
    with Blender's default blend 0.15 (:func:`spotnav.setup.geometry.edge_angle_of_blend`).
    """
    instrument = setup.instrument
    if instrument.edge_half_angle_deg is not None:
        return float(np.radians(instrument.edge_half_angle_deg))
    return edge_angle_of_blend(instrument.beam_half_angle, DEFAULT_BLEND)
