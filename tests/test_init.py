from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

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
