"""spotnav: localize a surgical instrument inside the eye from the light cone it projects.

The data flows one way: setup (:mod:`spotnav.config`) -> :mod:`spotnav.geometry`
-> :mod:`spotnav.camera` -> :mod:`spotnav.render` -> :mod:`spotnav.detect` ->
:mod:`spotnav.reconstruct` -> :mod:`spotnav.localize`, then
:mod:`spotnav.experiments` and :mod:`spotnav.cli`.
"""

from spotnav.config import Setup, SetupError, setup_from_toml
from spotnav.geometry import InstrumentPose
from spotnav.localize import PoseEstimate, localize
from spotnav.render import Renderer

__version__ = "0.1.0"

__all__ = [
    "InstrumentPose",
    "PoseEstimate",
    "Renderer",
    "Setup",
    "SetupError",
    "__version__",
    "localize",
    "setup_from_toml",
]
