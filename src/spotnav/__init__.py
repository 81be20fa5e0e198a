"""spotnav: localize a surgical instrument inside the eye from the light cone it projects.

The data flows one way, a package per stage: :mod:`spotnav.setup` -> :mod:`spotnav.optics` ->
:mod:`spotnav.image` -> :mod:`spotnav.pose`, with :mod:`spotnav.files` for what is read and written; then the
applications (:mod:`spotnav.app`), the studies (:mod:`spotnav.experiments`) and the command line
(:mod:`spotnav.cli`). ``docs/architecture.md`` draws the map.
"""

import hashlib
import importlib
from pathlib import Path
from typing import TYPE_CHECKING, Any


def _drop_stale_kernels() -> None:
    """Drop the compiled kernels cached beside the sources when any of the package's sources changed since.

    Numba keys each cached kernel on its own module's source only, and a kernel keeps the code of the kernels it
    calls in other modules: after a change to ``optics/camera.py`` alone (a ``git pull`` into an editable install),
    ``pose``'s cached kernels would go on computing with the old camera. Read-only sources (a cache under
    ``NUMBA_CACHE_DIR``) do not change, and are left alone.
    """
    package = Path(__file__).parent
    sources = sorted(package.rglob("*.py"))
    stamps = [(str(path.relative_to(package)), path.stat().st_size, path.stat().st_mtime_ns) for path in sources]
    fingerprint = hashlib.sha256(repr(stamps).encode()).hexdigest()
    marker = package / "__pycache__" / "spotnav-kernels-sources.txt"
    try:
        if marker.read_text() == fingerprint:
            return
    except OSError:
        pass
    try:
        marker.parent.mkdir(exist_ok=True)
        for cache in {path.parent / "__pycache__" for path in sources}:
            for kernel in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
                kernel.unlink(missing_ok=True)
        marker.write_text(fingerprint)
    except OSError:
        return


_drop_stale_kernels()

__version__ = "0.1.0"

# Where each name of the public API lives: imported on first use (PEP 562), so that ``import spotnav`` and the
# command line's start (``spotnav --version``) do not pay for NumPy, Numba, SciPy and OpenCV.
_EXPORTS = {
    "InstrumentPose": "spotnav.setup.geometry",
    "PoseEstimate": "spotnav.pose.estimate",
    "Renderer": "spotnav.optics.render",
    "Setup": "spotnav.setup.config",
    "SetupError": "spotnav.setup.values",
    "localize": "spotnav.pose.localize",
    "setup_from_toml": "spotnav.setup.config",
}

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

if TYPE_CHECKING:
    from spotnav.optics.render import Renderer
    from spotnav.pose.estimate import PoseEstimate
    from spotnav.pose.localize import localize
    from spotnav.setup.config import Setup, setup_from_toml
    from spotnav.setup.geometry import InstrumentPose
    from spotnav.setup.values import SetupError


def __getattr__(name: str) -> Any:
    """Import a name of the public API from its module on first use (``from spotnav import localize``)."""
    if name not in _EXPORTS:
        raise AttributeError(f"module 'spotnav' has no attribute {name!r}")
    value = getattr(importlib.import_module(_EXPORTS[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
