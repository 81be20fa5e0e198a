from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from spotnav.files.sequences import iter_frames


@pytest.mark.parametrize("ring", [0, 2])
def test_video_frames_decode_exactly_and_a_ring_reuses_its_buffers(
    tmp_path: Path, write_clip: Callable[..., tuple[Path, list[np.ndarray]]], ring: int
) -> None:
    clip, frames = write_clip(tmp_path, 4)
    decoded = []
    for frame in iter_frames(str(clip), ring=ring):
        np.testing.assert_array_equal(frame.pixels, frames[frame.index])  # lossless, as handed over
        decoded.append(frame.pixels)
    assert len(decoded) == 4
    assert (decoded[0] is decoded[2]) == (ring == 2) and decoded[0] is not decoded[1]


def test_a_negative_ring_is_refused_for_any_source(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="ring must be at least 0, got -1"):
        next(iter_frames(str(tmp_path), ring=-1))
