"""What a frame's work in a second process needs: a new interpreter running one of spotnav's functions, and anonymous
shared memory to hand frames over in (the video decoder, :mod:`spotnav.files.decoder`, and the recording's writer,
:mod:`spotnav.files.recording`)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

__all__ = ["shared_memory", "start_python"]


def shared_memory(size: int, name: str) -> int | None:
    """A file descriptor of ``size`` bytes of anonymous shared memory, allocated (so that no write to it can fail
    later), which no file names (nothing is left behind however the process ends); None where there is none or
    no room."""
    if not hasattr(os, "memfd_create"):
        return None
    descriptor = os.memfd_create(name)
    try:
        os.posix_fallocate(descriptor, 0, size)
    except OSError:
        os.close(descriptor)
        return None
    return descriptor


def start_python(main: str, arguments: list[str], **options: Any) -> subprocess.Popen[bytes]:
    """Run ``main`` (``"module:function"``, of spotnav's) in a new interpreter (not a fork: OpenCV's threads do not
    survive one), with ``arguments`` as its ``sys.argv[1:]``, spotnav imported from where this process imports it;
    ``options`` go to :class:`subprocess.Popen`.

    Raises
    ------
    OSError
        If the process cannot be started.
    """
    module, function = main.split(":")
    package_root = str(Path(__file__).resolve().parents[2])
    paths = [package_root, *filter(None, [os.environ.get("PYTHONPATH")])]
    code = f"import {module} as m; m.{function}()"
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}
    return subprocess.Popen([sys.executable, "-P", "-c", code, *arguments], env=environment, **options)
