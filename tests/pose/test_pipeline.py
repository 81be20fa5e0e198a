"""The one frame pipeline: the methods configure the same stages, and every stage fails with a status."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from spotnav.app import calibrate, track
from spotnav.experiments.scenes import thesis_world, with_true_edge
from spotnav.optics.camera import project_points
from spotnav.optics.render import Renderer
from spotnav.pose import precise
from spotnav.pose.conefit import edge_angle
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.pipeline import LightReading, fit_visible, fitted_edges_px
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose, beam_axes, cone_sphere_curve
from spotnav.setup.paths import helix_tips, poses_through_insertion

SIZE_PX = 768


def world(beams: int = 1, **faults: float) -> Setup:
    setup = with_true_edge(thesis_world(SIZE_PX, beams))
    return replace(setup, faults=replace(setup.faults, **faults)) if faults else setup


def helix_pose(setup: Setup, index: int) -> InstrumentPose:
    return poses_through_insertion(helix_tips(300)[index : index + 1], setup.instrument.insertion_in_eye)[0]


def truth_of(pose: InstrumentPose) -> PoseEstimate:
    return PoseEstimate("ok", tip_in_eye=pose.tip_in_eye, axis=pose.axis)


def distances_to_true_edge_px(setup: Setup, pose: InstrumentPose, beam: int, points_px: np.ndarray) -> np.ndarray:
    """Each point's distance (N,) from the true edge curve of ``beam`` in the image, pixels."""
    instrument, eye = setup.instrument, setup.eye
    angle = edge_angle(setup)
    axis = beam_axes(pose.axis, instrument.beam_count, instrument.beam_tilt)[beam]
    apex = pose.tip_in_eye - axis * instrument.light_radius_mm / np.tan(angle)
    curve = project_points(setup.camera, cone_sphere_curve(apex, axis, angle, eye.center_in_eye, eye.radius_mm, 4000))
    return np.min(np.linalg.norm(points_px[:, None, :] - curve[None, :, :], axis=2), axis=1)


def three_readings(image: np.ndarray, setup: Setup, pose: InstrumentPose) -> dict[str, LightReading | PoseEstimate]:
    """The read stage as the whole-frame method, the tracker (from the true pose) and calibration configure it."""
    found = precise.prepare_edges(image, precise.detect_spots(image, setup), setup, True)
    known = calibrate._frame_edges(calibrate.KnownFrame("known", image, pose.tip_in_eye, pose.axis), setup)
    return {
        "whole frame": found if isinstance(found, PoseEstimate) else found.reading,
        "tracking": track._read_predicted_edges(image, setup, truth_of(pose), 128),
        "calibration": known if isinstance(known, PoseEstimate) else known.reading,
    }


@pytest.mark.parametrize("beams", [1, 3])
def test_every_method_reads_the_same_light_on_the_true_edge(beams: int) -> None:
    setup = world(beams)
    pose = helix_pose(setup, 40)
    image = Renderer(setup).render(pose, seed=40)
    readings = three_readings(image, setup, pose)
    for how, reading in readings.items():
        assert isinstance(reading, LightReading), f"{how}: {reading}"
        assert sorted(reading.beams) == list(range(beams))
        nearest = []
        for edge in reading.edges:
            # Three beams' labels may turn by a third (the roll's symmetry): each edge lies on one true beam's curve.
            medians = [np.median(distances_to_true_edge_px(setup, pose, beam, edge.pixels)) for beam in range(beams)]
            nearest.append(int(np.argmin(medians)))
            # The edge reader on this frame: some 0.1 px from the true curve; another beam's is pixels off.
            assert min(medians) < 0.2, how
            assert len(edge.pixels) > 0.5 * edge.rays, how
        assert sorted(nearest) == list(range(beams)), how
    # One judge: each spot's own whole-edge sigma agrees between the configurations (they read other rays).
    whole, tracked = readings["whole frame"], readings["tracking"]
    assert isinstance(whole, LightReading) and isinstance(tracked, LightReading)
    assert 0.5 < np.mean(tracked.sigmas) / np.mean(whole.sigmas) < 2.0


def test_a_frame_blurred_past_reading_is_refused_blurred_by_every_method() -> None:
    setup = world(frame_blur_px=3.0)
    pose = helix_pose(setup, 40)
    image = Renderer(setup).render(pose, seed=40)
    for how, reading in three_readings(image, setup, pose).items():
        assert isinstance(reading, PoseEstimate) and reading.status == "blurred", f"{how}: {reading}"
    known = calibrate._frame_edges(calibrate.KnownFrame("cal_07", image, pose.tip_in_eye), setup)
    assert isinstance(known, PoseEstimate) and known.detail.startswith("cal_07: ")


def test_a_spot_not_where_it_was_predicted_is_a_status() -> None:
    setup = world()
    pose = helix_pose(setup, 40)
    image = Renderer(setup).render(pose, seed=40)
    away = replace(truth_of(pose), tip_in_eye=pose.tip_in_eye + np.array([1.5, 0.0, 0.0]))
    read = track._read_predicted_edges(image, setup, away, 128)
    assert isinstance(read, PoseEstimate)
    assert read.status == "unreliable" and "near the predicted spot" in read.detail


def test_the_fit_stage_fits_what_the_shaft_leaves_and_refuses_what_it_hides() -> None:
    setup = world()
    pose = helix_pose(setup, 40)
    image = Renderer(setup).render(pose, seed=40)
    reading = track._read_predicted_edges(image, setup, truth_of(pose), 128)
    assert isinstance(reading, LightReading)
    start = pose.tip_in_eye + np.array([0.05, -0.03, 0.04])
    nothing = [np.zeros(len(edge), dtype=bool) for edge in reading.edges_px]
    fit = fit_visible(setup, reading, nothing, start, pose.axis, 0.0, solver="gauss-newton")
    assert not isinstance(fit, PoseEstimate)
    assert np.linalg.norm(fit.tip() - pose.tip_in_eye) < 0.01
    assert np.array_equal(fitted_edges_px(fit)[0], reading.edges_px[0])
    half = [np.arange(len(edge)) < 0.7 * len(edge) for edge in reading.edges_px]
    refused = fit_visible(setup, reading, half, start, pose.axis, 0.0)
    assert isinstance(refused, PoseEstimate) and refused.status == "occluded"
