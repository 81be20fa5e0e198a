from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import spotnav


def _import_package(root: Path) -> None:
    subprocess.run([sys.executable, "-c", "import spotnav"], cwd=root, check=True, env={"PYTHONPATH": str(root)})


def test_cached_kernels_are_dropped_when_any_source_changes(tmp_path: Path) -> None:
    # Numba keys a cached kernel on its own module only, and a kernel keeps the code of those it calls in other
    # modules: a change to any source drops every kernel cached beside the sources; an unchanged package keeps them.
    package = tmp_path / "spotnav"
    shutil.copytree(Path(spotnav.__file__).parent, package, ignore=shutil.ignore_patterns("__pycache__"))
    _import_package(tmp_path)
    (package / "pose" / "__pycache__").mkdir(exist_ok=True)
    kernels = [
        package / "pose" / "__pycache__" / name for name in ("conefit._residuals-1.py311.nbi", "conefit.x.py311.1.nbc")
    ]
    for kernel in kernels:
        kernel.write_bytes(b"cached")
    _import_package(tmp_path)
    assert all(kernel.exists() for kernel in kernels)
    with (package / "optics" / "camera.py").open("a") as source:
        source.write("\n")
    _import_package(tmp_path)
    assert not any(kernel.exists() for kernel in kernels)
    assert (package / "__pycache__" / "spotnav-kernels-sources.txt").exists()


HEAVY = ("numpy", "numba", "scipy", "cv2", "matplotlib", "pandas", "dask", "distributed", "pyigtl", "PIL")


def _imported_after(code: str) -> list[str]:
    """The heavy packages that ``code`` imports, run in a fresh interpreter."""
    check = f"{code}\nimport sys\nprint(' '.join(sorted({{name.split('.')[0] for name in sys.modules}})))"
    result = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, check=True)
    return sorted(set(result.stdout.split()) & set(HEAVY))


def test_the_package_and_the_command_line_import_the_standard_library_only() -> None:
    # Issue 44: every command paid 2.6 s of imports before it began, and `spotnav --version` as much.
    assert _imported_after("import spotnav") == []
    assert _imported_after("import spotnav.cli, spotnav.arguments") == []


def test_the_public_names_load_on_first_use() -> None:
    from spotnav import InstrumentPose, PoseEstimate, Renderer, Setup, SetupError, localize, setup_from_toml
    from spotnav.optics.render import Renderer as RendererItself
    from spotnav.pose.localize import localize as localize_itself

    assert Renderer is RendererItself and localize is localize_itself
    exported = {getattr(spotnav, name) for name in spotnav.__all__}
    assert {InstrumentPose, PoseEstimate, Setup, SetupError, setup_from_toml} <= exported
    assert set(spotnav.__all__) <= set(dir(spotnav))
    assert "numpy" in _imported_after("from spotnav import localize")
    with pytest.raises(AttributeError, match="no_such_name"):
        spotnav.no_such_name  # noqa: B018
