from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import small_setup

from spotnav.calibrate import Calibration, KnownFrame, calibrate_edge, self_calibrate_radius
from spotnav.config import Instrument, Setup, World
from spotnav.experiments import helix_tips, working_volume_tips
from spotnav.geometry import InstrumentPose, edge_angle_of_blend
from spotnav.render import Renderer


def known_frames(setup: Setup, count: int = 8, seed: int = 5) -> list[KnownFrame]:
    renderer = Renderer(setup)
    frames = []
    for i, tip in enumerate(working_volume_tips(count, seed=seed)):
        pose = InstrumentPose.through_insertion(tip, setup.instrument.insertion_in_eye)
        frames.append(KnownFrame(f"frame {i}", renderer.render(pose, seed=i), tip))
    return frames


def test_calibration_round_trip_edge_angle() -> None:
    # A beam softer than the default model (blend 0.3): 8 known frames recover its half-light angle.
    setup = small_setup(1024, blend=0.3)
    result = calibrate_edge(known_frames(setup), setup)
    truth = np.degrees(edge_angle_of_blend(setup.instrument.beam_half_angle, 0.3))
    assert result.edge_half_angle_deg == pytest.approx(truth, abs=max(4 * result.edge_sigma_deg, 0.02))
    assert result.rms_after_deg < 0.5 * result.rms_before_deg
    assert result.frames == 8 and np.isnan(result.radius_sigma_mm)
    calibrated = result.apply(setup)
    assert calibrated.instrument.edge_half_angle_deg == result.edge_half_angle_deg


def test_a_point_light_calibrates_to_no_light_radius() -> None:
    # spotnav's renderer has a point light: fitting the light's radius must not invent one (it widens
    # the edge by 0.02 mm in the Cycles frames, a tenth of a degree at 5 mm).
    setup = small_setup(1024, blend=0.3)
    result = calibrate_edge(known_frames(setup), setup, fit_light_radius=True)
    assert abs(result.light_radius_mm) < max(4 * result.light_radius_sigma_mm, 0.003)
    truth = np.degrees(edge_angle_of_blend(setup.instrument.beam_half_angle, 0.3))
    assert result.edge_half_angle_deg == pytest.approx(truth, abs=0.05)
    assert result.apply(setup).instrument.light_radius_mm == result.light_radius_mm


def test_calibration_round_trip_radius_three_beams() -> None:
    # The true eye is 13.5 mm, the setup says 12.5: the joint fit finds the radius within 0.1 mm.
    base = small_setup(1024, blend=0.15)
    setup = replace(base, instrument=Instrument(beam_count=3), world=World(eye_radius_mm=13.5))
    result = calibrate_edge(known_frames(setup), setup, fit_radius=True)
    assert result.radius_mm == pytest.approx(13.5, abs=0.1)
    assert 0 < result.radius_sigma_mm < 0.1
    assert result.apply(setup).eye.radius_mm == result.radius_mm


def test_calibration_refuses_too_few_or_degenerate_frames() -> None:
    setup = small_setup(512, blend=0.15)
    frames = known_frames(setup, count=2)
    with pytest.raises(ValueError, match="at least 3 usable frames"):
        calibrate_edge(frames, setup)
    renderer = Renderer(setup)
    same = InstrumentPose.through_insertion([1.0, 1.0, 4.0], setup.instrument.insertion_in_eye)
    repeated = [KnownFrame(f"f{i}", renderer.render(same, seed=i), same.tip_in_eye) for i in range(5)]
    with pytest.raises(ValueError, match="degenerate"):
        calibrate_edge(repeated, setup, fit_radius=True)
    with pytest.raises(ValueError, match=r"4\.00-4\.00 mm above the pole"):
        calibrate_edge(repeated, setup, fit_light_radius=True)
    dark = [KnownFrame("dark", renderer.render(same, power_w=0.0), same.tip_in_eye), *frames]
    with pytest.raises(ValueError, match="dark: 0 whole spots"):
        calibrate_edge(dark, setup)


def test_calibration_apply_keeps_the_rest() -> None:
    result = Calibration(8.5, 0.01, 12.7, 0.02, 0.03, 0.001, 0.3, 0.05, 5, 900)
    setup = small_setup(256)
    calibrated = result.apply(setup)
    assert calibrated.camera == setup.camera and calibrated.light == setup.light
    assert calibrated.eye.radius_mm == 12.7 and calibrated.instrument.edge_half_angle_deg == 8.5


def test_self_calibration_of_the_radius_from_a_sequence() -> None:
    # 20 helix frames in a 13.5 mm eye that the setup calls 12.5 mm, poses unknown: the joint fit
    # finds the radius within 0.1 mm and the tips to a few hundredths of a millimetre.
    setup = replace(small_setup(768, blend=0.15), world=World(eye_radius_mm=13.5))
    renderer = Renderer(setup)
    tips = helix_tips(20)
    images = [
        renderer.render(InstrumentPose.through_insertion(tip, setup.instrument.insertion_in_eye), seed=i)
        for i, tip in enumerate(tips)
    ]
    result = self_calibrate_radius(images, setup)
    assert result.radius_mm == pytest.approx(13.5, abs=0.1)
    assert result.frames == 20
    errors = [np.linalg.norm(e.tip_in_eye - t) for e, t in zip(result.estimates, tips, strict=True)]
    assert max(errors) < 0.05
    assert all("eye radius fitted" in e.detail for e in result.estimates)
    with pytest.raises(ValueError, match="at least 20 frames"):
        self_calibrate_radius(images[:10], setup)
