from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import spotnav.pose.estimate
from spotnav.pose.estimate import STATUSES, PoseEstimate


def test_estimate_invariants() -> None:
    with pytest.raises(ValueError, match="status"):
        PoseEstimate("fine")
    with pytest.raises(ValueError, match="exactly when"):
        PoseEstimate("no_spot", tip_in_eye=np.zeros(3), axis=np.array([0, 0, 1.0]))


def test_every_status_is_documented_where_users_read_it() -> None:
    # The module's docstring and the README list the same statuses as STATUSES, in its order.
    documented = re.findall(r"^``(\w+)``$", spotnav.pose.estimate.__doc__ or "", re.MULTILINE)
    assert documented == list(STATUSES)
    readme = (Path(__file__).parents[2] / "README.md").read_text()
    listed = re.search(r"\(`no_spot`.*?; `spotnav.pose.estimate`\)", readme, re.DOTALL)
    assert listed is not None
    assert re.findall(r"`(\w+)`", listed.group(0)) == [s for s in STATUSES if s != "ok"]
