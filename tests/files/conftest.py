"""Fixtures of the file tests: a lossless video clip of noise frames."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from spotnav.files.sequences import SequenceWriter

ClipWriter = Callable[..., tuple[Path, list[np.ndarray]]]
"""Writes a clip into a folder: ``write_clip(folder, count, shape=(48, 64))`` -> (its path, its frames)."""


def _clip(tmp_path: Path, count: int, shape: tuple[int, int] = (48, 64)) -> tuple[Path, list[np.ndarray]]:
    """An FFV1 clip of ``count`` noise frames of ``shape`` (rows, columns), and the frames."""
    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 256, (*shape, 3), dtype=np.uint8) for _ in range(count)]
    with SequenceWriter(tmp_path / "clip.mkv", fps=30.0) as writer:
        for index, rgb in enumerate(frames):
            writer.write(index, rgb)
    return tmp_path / "clip.mkv", frames


@pytest.fixture
def write_clip() -> ClipWriter:
    """:func:`_clip`: an FFV1 clip of noise frames in a folder, and the frames."""
    return _clip
