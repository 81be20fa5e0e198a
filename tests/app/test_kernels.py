from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numba
import pytest
from test_cli import write_scene

from spotnav.app import kernels

SPOTNAV = Path(sys.executable).parent / "spotnav"

UNCACHED = """
import importlib, os, pkgutil, spotnav
from numba.core.registry import CPUDispatcher
from spotnav.app.kernels import kernels_compiled, warm_kernels
if not kernels_compiled():
    warm_kernels()
for info in pkgutil.walk_packages(spotnav.__path__, "spotnav."):
    for name, kernel in vars(importlib.import_module(info.name)).items():
        if isinstance(kernel, CPUDispatcher) and kernel.__module__ == info.name:
            inlined = kernel.targetoptions.get("inline") == "always"  # compiled inside its callers only
            if not inlined and not os.path.exists(kernel._cache._cache_file._index_path):
                print(f"{info.name}.{name}")
"""


def test_the_mark_follows_numba_cache_dir_and_the_sources(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    cache = kernels.kernel_cache()
    assert cache is not None and tmp_path in cache.parents
    assert not kernels.kernels_compiled()  # an empty cache
    (cache / "spotnav-kernels-compiled.txt").write_text(kernels._fingerprint())
    assert kernels.kernels_compiled()
    (cache / "spotnav-kernels-compiled.txt").write_text("the sources as they were before a change")
    assert not kernels.kernels_compiled()


def _uncached_kernels(env: dict[str, str]) -> list[str]:
    """The package's compiled kernels that Numba's cache lacks once it is marked compiled (warmed first if not)."""
    result = subprocess.run([sys.executable, "-c", UNCACHED], capture_output=True, text=True, check=True, env=env)
    return result.stdout.split()


def test_the_cache_holds_every_kernel() -> None:
    # Issue 44: calibrate compiled a dozen kernels that localize had not, silently. Once the cache is marked
    # compiled, it holds every compiled kernel of the package (but those inlined into their callers).
    assert _uncached_kernels(dict(os.environ)) == []


@pytest.mark.slow
def test_warming_compiles_every_kernel(tmp_path: Path) -> None:
    # The same from an empty cache: warm_kernels alone, in its processes, compiles every kernel.
    assert _uncached_kernels({**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}) == []


def _group_alive(group: int, wait_s: float) -> bool:
    """Whether a process of ``group`` is still alive after up to ``wait_s`` s."""
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        try:
            os.killpg(group, 0)
        except ProcessLookupError:
            return False
        time.sleep(0.1)
    return True


def test_an_interrupted_compilation_leaves_no_worker_and_no_mark(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    cache.mkdir()
    scene = write_scene(tmp_path / "setup.toml", size_px=256)
    argv = [str(SPOTNAV), "render", "--scene", str(scene), "--tip", "1", "1", "5", "--out", str(tmp_path / "f.png")]
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    process = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True, env=env, start_new_session=True)
    deadline = time.monotonic() + 600  # a hang's guard, not a speed limit
    while time.monotonic() < deadline and not any(cache.rglob("*.nbi")):  # the workers are compiling
        time.sleep(0.1)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=600)
    assert process.returncode == 130 and err.splitlines()[-1] == "spotnav: interrupted" and "Traceback" not in err
    assert err.count("compiling spotnav's numerical kernels once") == 1
    assert not _group_alive(process.pid, 600.0)  # the workers ended with the command
    assert not list(cache.rglob("spotnav-kernels-compiled.txt"))
