"""Self-calibration of the eye's radius from a sequence of frames at unknown poses."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import small_setup

from spotnav.errors import SpotnavError
from spotnav.experiments.chapter6 import with_true_edge
from spotnav.optics.render import Renderer
from spotnav.pose.self_calibration import self_calibrate_radius
from spotnav.setup.config import World
from spotnav.setup.geometry import InstrumentPose
from spotnav.setup.paths import helix_tips


def test_self_calibration_of_the_radius_from_a_sequence() -> None:
    # 20 helix frames in a 13.5 mm eye that the setup calls 12.5 mm, poses unknown: the joint fit
    # finds the radius within 0.1 mm and the tips to a few hundredths of a millimetre.
    world = replace(small_setup(768, blend=0.15), world=World(eye_radius_mm=13.5))
    setup = with_true_edge(world)
    renderer = Renderer(world)
    tips = helix_tips(20)
    images = [
        renderer.render(InstrumentPose.through_insertion(tip, world.instrument.insertion_in_eye), seed=i)
        for i, tip in enumerate(tips)
    ]
    result = self_calibrate_radius(images, setup)
    assert result.radius_mm == pytest.approx(13.5, abs=0.1)
    assert result.frames == 20
    errors = [np.linalg.norm(e.tip_in_eye - t) for e, t in zip(result.estimates, tips, strict=True)]
    assert max(errors) < 0.05
    assert all("eye radius fitted" in e.detail for e in result.estimates)
    with pytest.raises(SpotnavError, match="at least 20 frames"):
        self_calibrate_radius(images[:10], setup)
