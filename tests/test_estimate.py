from __future__ import annotations

import numpy as np
import pytest

from spotnav.estimate import PoseEstimate


def test_estimate_invariants() -> None:
    with pytest.raises(ValueError, match="status"):
        PoseEstimate("fine")
    with pytest.raises(ValueError, match="exactly when"):
        PoseEstimate("no_spot", tip_in_eye=np.zeros(3), axis=np.array([0, 0, 1.0]))
