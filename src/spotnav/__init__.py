"""spotnav: localize a surgical instrument inside the eye from the light cone it projects.

The data flows one way, a package per stage: :mod:`spotnav.setup` -> :mod:`spotnav.optics` ->
:mod:`spotnav.image` -> :mod:`spotnav.pose`, with :mod:`spotnav.files` for what is read and written; then the
applications (:mod:`spotnav.app`), the studies (:mod:`spotnav.experiments`) and the command line
(:mod:`spotnav.cli`). ``docs/architecture.md`` draws the map.
"""

import os

TYPE_CHECKING = False  # mypy reads the imports below; at run time each name is imported on first use (PEP 562)
if TYPE_CHECKING:
    from spotnav.optics.render import Renderer
    from spotnav.pose.estimate import PoseEstimate
    from spotnav.pose.localize import localize
    from spotnav.setup.config import Setup, setup_from_toml
    from spotnav.setup.geometry import InstrumentPose
    from spotnav.setup.values import SetupError


def _sources(package: str) -> list[str]:
    """The package's ``.py`` files, sorted, as paths from ``package``."""
    found: list[str] = []
    for folder, folders, files in os.walk(package):
        folders[:] = [name for name in folders if name != "__pycache__"]
        found.extend(os.path.join(folder, name) for name in files if name.endswith(".py"))
    return sorted(found)


def _sources_fingerprint(package: str, sources: list[str]) -> str:
    """Each source's name, size and change time, a line each: what the compiled kernels were built from.

    Raises
    ------
    OSError
        If a source cannot be read.
    """
    stamps = [(os.path.relpath(path, package), os.stat(path)) for path in sources]
    return "\n".join(f"{name} {stat.st_size} {stat.st_mtime_ns}" for name, stat in stamps)


def _drop_stale_kernels() -> None:
    """Drop the compiled kernels cached beside the sources when any of the package's sources changed since.

    Numba keys each cached kernel on its own module's source only, and a kernel keeps the code of the kernels it
    calls in other modules: after a change to ``optics/camera.py`` alone (a ``git pull`` into an editable install),
    ``pose``'s cached kernels would go on computing with the old camera. Read-only sources (a cache under
    ``NUMBA_CACHE_DIR``) do not change, and are left alone. The standard library's ``os`` only: this runs at every
    start, before the command line can catch an interrupt.
    """
    package = os.path.dirname(os.path.abspath(__file__))
    sources = _sources(package)
    try:
        fingerprint = _sources_fingerprint(package, sources)
    except OSError:
        return
    marker = os.path.join(package, "__pycache__", "spotnav-kernels-sources.txt")
    try:
        with open(marker, encoding="utf-8") as handle:
            if handle.read() == fingerprint:
                return
    except OSError:
        pass
    try:
        os.makedirs(os.path.dirname(marker), exist_ok=True)
        for cache in {os.path.join(os.path.dirname(path), "__pycache__") for path in sources}:
            for name in os.listdir(cache) if os.path.isdir(cache) else []:
                if name.endswith((".nbi", ".nbc")):
                    os.unlink(os.path.join(cache, name))
        with open(marker, "w", encoding="utf-8") as handle:
            handle.write(fingerprint)
    except OSError:
        return


_drop_stale_kernels()

__version__ = "0.1.0"

# Where each name of the public API lives, imported on first use, so that ``import spotnav`` and the
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


def __getattr__(name: str) -> object:
    """Import a name of the public API from its module on first use (``from spotnav import localize``)."""
    if name not in _EXPORTS:
        raise AttributeError(f"module 'spotnav' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(_EXPORTS[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
