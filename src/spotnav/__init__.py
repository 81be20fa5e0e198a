"""spotnav: localize a surgical instrument inside the eye from the light cone it projects.

The data flows one way, a package per stage: :mod:`spotnav.setup` -> :mod:`spotnav.optics` ->
:mod:`spotnav.image` -> :mod:`spotnav.pose`, with :mod:`spotnav.files` for what is read and written; then the
applications (:mod:`spotnav.app`), the studies (:mod:`spotnav.experiments`) and the command line
(:mod:`spotnav.cli`). ``docs/architecture.md`` draws the map.
"""

import hashlib
from pathlib import Path


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

from spotnav.optics.render import Renderer  # noqa: E402
from spotnav.pose.estimate import PoseEstimate  # noqa: E402
from spotnav.pose.localize import localize  # noqa: E402
from spotnav.setup.config import Setup, setup_from_toml  # noqa: E402
from spotnav.setup.geometry import InstrumentPose  # noqa: E402
from spotnav.setup.values import SetupError  # noqa: E402

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
