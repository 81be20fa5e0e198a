from __future__ import annotations

from pathlib import Path

import pytest

from spotnav.files.sequences import iter_frames


def test_a_negative_ring_is_refused_for_any_source(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="ring must be at least 0, got -1"):
        next(iter_frames(str(tmp_path), ring=-1))
