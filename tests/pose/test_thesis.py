"""The thesis's method's own parts: section 5.5's height correction."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import small_setup

from spotnav.optics.render import Renderer
from spotnav.pose.localize import localize
from spotnav.pose.thesis import fit_height_correction
from spotnav.setup.geometry import InstrumentPose
from spotnav.setup.paths import working_volume_tips


def test_height_correction_removes_the_soft_edge_bias() -> None:
    # Section 5.5: one frame at a known pose gives the factor; it cuts the soft edge's error.
    setup = small_setup(1024, blend=0.15)
    renderer = Renderer(setup)
    known = InstrumentPose.through_insertion([0.0, 0.0, 4.5], setup.instrument.insertion_in_eye)
    factor = fit_height_correction(renderer.render(known, seed=50), setup, known.tip_in_eye).factor
    assert 1.01 < factor < 1.1
    calibrated = replace(setup, instrument=replace(setup.instrument, height_correction=factor))
    plain_errors, calibrated_errors = [], []
    for i, tip in enumerate(working_volume_tips(6, seed=2)):
        image = renderer.render(InstrumentPose.through_insertion(tip, setup.instrument.insertion_in_eye), seed=i)
        plain_errors.append(np.linalg.norm(localize(image, setup, "thesis").tip_in_eye - tip))
        calibrated_errors.append(np.linalg.norm(localize(image, calibrated, "thesis").tip_in_eye - tip))
    assert np.mean(calibrated_errors) < 0.5 * np.mean(plain_errors)


def test_height_correction_is_one_for_a_sharp_edge(renderer_2048: Renderer) -> None:
    setup = renderer_2048.setup
    known = InstrumentPose.through_insertion([0.0, 0.0, 4.5], setup.instrument.insertion_in_eye)
    factor = fit_height_correction(renderer_2048.render(known, seed=3), setup, known.tip_in_eye).factor
    assert factor == pytest.approx(1.0, abs=0.01)


def test_height_correction_needs_a_spot(renderer_512: Renderer) -> None:
    dark = renderer_512.render(InstrumentPose([0.0, 0.0, 4.0], [0.0, 0.0, -1.0]), power_w=0.0)
    refused = fit_height_correction(dark, renderer_512.setup, np.array([0.0, 0.0, 4.0]))
    assert refused.status == "no_spot"
    assert "no whole spot" in refused.detail
