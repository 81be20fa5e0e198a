"""spotnav: localize a surgical instrument inside the eye from the light cone it projects.

The data flows one way: setup (:mod:`spotnav.config`) -> :mod:`spotnav.geometry`
-> :mod:`spotnav.camera` -> :mod:`spotnav.render` -> :mod:`spotnav.detect` ->
:mod:`spotnav.reconstruct` -> :mod:`spotnav.localize`, then
:mod:`spotnav.experiments` and :mod:`spotnav.cli`.
"""

import hashlib
from pathlib import Path


def _drop_stale_kernels() -> None:
    """Drop the compiled kernels cached beside the sources when any of the package's sources changed since.

    Numba keys each cached kernel on its own module's source only, and a kernel keeps the code of the kernels it
    calls in other modules: after a change to ``camera.py`` alone (a ``git pull`` into an editable install),
    ``conefit``'s cached kernels would go on computing with the old camera. Read-only sources (a cache under
    ``NUMBA_CACHE_DIR``) do not change, and are left alone.
    """
    package = Path(__file__).parent
    cache = package / "__pycache__"
    stamps = [(path.name, path.stat().st_size, path.stat().st_mtime_ns) for path in sorted(package.glob("*.py"))]
    fingerprint = hashlib.sha256(repr(stamps).encode()).hexdigest()
    marker = cache / "spotnav-kernels-sources.txt"
    try:
        if marker.read_text() == fingerprint:
            return
    except OSError:
        pass
    try:
        cache.mkdir(exist_ok=True)
        for kernel in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
            kernel.unlink(missing_ok=True)
        marker.write_text(fingerprint)
    except OSError:
        return


_drop_stale_kernels()

from spotnav.config import Setup, SetupError, setup_from_toml  # noqa: E402
from spotnav.geometry import InstrumentPose  # noqa: E402
from spotnav.localize import PoseEstimate, localize  # noqa: E402
from spotnav.render import Renderer  # noqa: E402

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
