from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import small_setup
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav.app.track import Tracker
from spotnav.optics.render import Renderer
from spotnav.pose.sequence import MEETING_SIGMAS, MIN_LINES, POSE_SPACING_MM, AxesMeeting, AxisLine
from spotnav.setup.geometry import InstrumentPose, normalize
from spotnav.setup.paths import helix_tips

SETUP = small_setup(512)
INSERTION = SETUP.instrument.insertion_in_eye


def _lines(pivot: np.ndarray, count: int, seed: int, angle_sigma: float = np.radians(0.3)) -> list[AxisLine]:
    """Axes through ``pivot`` to tips over the helix's region, each turned by its own noise (the stated sigma)."""
    rng = np.random.default_rng(seed)
    lines = []
    for _ in range(count):
        tip = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(3, 6)])
        axis = normalize(normalize(tip - pivot) + rng.normal(0.0, angle_sigma, 3))
        lines.append(AxisLine(tip, axis, angle_sigma**2, 1e-6))
    return lines


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_axes_through_the_setup_s_insertion_point_never_make_the_test_speak(seed: int) -> None:
    meeting = AxesMeeting(SETUP)
    assert not any(meeting.add(line) for line in _lines(INSERTION, 200, seed))
    point, covariance = meeting.meeting_point()
    # The meeting point lies on the plane across the axes through the insertion point, within its sigmas of it.
    miss = point - INSERTION
    assert np.linalg.norm(miss) < MEETING_SIGMAS * np.sqrt(np.trace(covariance))


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**16), shift=st.sampled_from([(0.5, 0.0, 0.0), (0.0, 0.4, 0.0), (-0.3, 0.3, 0.0)]))
def test_axes_through_another_point_make_the_test_speak_once_and_name_it(seed: int, shift: tuple) -> None:
    pivot = INSERTION + np.array(shift)
    meeting = AxesMeeting(SETUP)
    said = [meeting.add(line) for line in _lines(pivot, 100, seed)]
    spoken = [i for i, verdict in enumerate(said) if verdict]
    assert len(spoken) == 1 and spoken[0] >= MIN_LINES - 1
    assert meeting.verdict == said[spoken[0]] and "spotnav calibrate --poses known.csv" in meeting.verdict
    where = [float(v) for v in meeting.verdict.split("(at [")[1].split("]")[0].split(",")]
    # Where the axes cross the plane through the setup's point: the true pivot, less its shift along the axes.
    across = meeting._crossing()[0]
    np.testing.assert_allclose(across.T @ np.array(where), across.T @ pivot, atol=0.1)


def test_a_tracked_instrument_pivoting_elsewhere_is_flagged_after_the_sequence_test_speaks() -> None:
    """One beam, the world's insertion point 1 mm from the setup's: single frames fit (the tip slides along its
    line), the axes of the moving instrument miss the setup's point; after the test speaks every frame is
    ``mismatch`` with its verdict. The same helix about the setup's point is never flagged."""
    world = replace(SETUP, instrument=replace(SETUP.instrument, insertion_point_mm=(1.0, 6.0, 20.0)))
    angles = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    tips = np.stack([1.5 * np.cos(angles), 1.5 * np.sin(angles), np.linspace(3.0, 6.0, 24)], axis=1)
    for truth, flagged in ((world, True), (SETUP, False)):
        renderer, tracker = Renderer(truth), Tracker(SETUP)
        poses = [InstrumentPose.through_insertion(tip, truth.instrument.insertion_in_eye) for tip in tips]
        statuses = [tracker.update(renderer.render(pose, seed=i)).estimate for i, pose in enumerate(poses)]
        if not flagged:
            assert not tracker.sequence.verdict and all(e.ok for e in statuses), [e.detail for e in statuses]
            continue
        assert tracker.sequence.verdict, f"{tracker.sequence.lines} lines heard, no verdict"
        # Some single frames say so too (their residuals widen sigma past the limit: mismatch); from the frame the
        # sequence spoke on, no frame has a pose, and those that would have carry its verdict.
        first = next(i for i, e in enumerate(statuses) if e.detail == tracker.sequence.verdict)
        assert not any(e.ok for e in statuses[first:])
        flagged = [e for e in statuses[first:] if e.detail == tracker.sequence.verdict]
        assert all(e.status == "mismatch" for e in flagged) and len(flagged) >= 2
        assert "insertion point" in tracker.sequence.verdict


def test_a_line_without_a_finite_variance_is_not_heard() -> None:
    meeting = AxesMeeting(SETUP)
    line = _lines(INSERTION, 1, 0)[0]
    assert meeting.add(replace(line, angle_variance=float("nan"))) == "" and meeting.lines == 0
    with pytest.raises(np.linalg.LinAlgError):
        meeting.meeting_point()  # nothing heard: no point


def _pose_locked_lines(pivot: np.ndarray, tips: np.ndarray, seed: int) -> list[AxisLine]:
    """Axes through ``pivot`` to ``tips``, each turned by the frame's noise (its stated sigma, 1 deg) and by as
    much again that belongs to its pose: a smooth random field of the tip, correlated 0.67 over 0.1 mm, 0.2 over
    0.2 mm, nil over 0.5 mm, as a free axis's edge-model error is on the rendered helix (a little more: the module
    docstring of spotnav.pose.sequence)."""
    rng = np.random.default_rng(seed)
    sigma = np.radians(1.0)
    waves = rng.normal(0.0, 2.0 * np.pi / 0.7, (32, 3))  # wave vectors, rad/mm
    phases = rng.uniform(0.0, 2.0 * np.pi, (32, 3))
    pose_error = np.sqrt(2.0 / 32) * sigma * np.stack([np.sin(tips @ waves.T + p).sum(axis=1) for p in phases.T], 1)
    lines = []
    for tip, bias in zip(tips, pose_error, strict=True):
        axis = normalize(normalize(tip - pivot) + bias + rng.normal(0.0, sigma, 3))
        lines.append(AxisLine(tip, axis, sigma**2, 1e-4))
    return lines


@pytest.mark.parametrize(("frames", "seed"), [(1000, 0), (1000, 1), (3000, 0), (3000, 1)])
def test_a_long_session_of_lines_whose_error_is_their_pose_s_raises_no_alarm(frames: int, seed: int) -> None:
    """The helix in 1000 or 3000 frames, its lines' error half the frame's noise (as stated), half their pose's
    (the same for frames a few hundredths of a mm apart): heard a pose at a time, their meeting point stays within
    its sigmas of the insertion point."""
    lines = _pose_locked_lines(INSERTION, helix_tips(frames), seed)
    meeting = AxesMeeting(SETUP)
    assert not any(meeting.add(line) for line in lines)
    assert MIN_LINES < meeting.lines < 100  # one line a pose: some 50 over the helix's 25 mm


def test_heard_a_frame_at_a_time_the_pose_s_error_makes_the_test_speak() -> None:
    """The same 3000 lines heard a frame at a time: their pose's share never averages out, and the test speaks
    within the first few dozen frames (the issue's false alarm, 19 frames into a 3000-frame helix)."""
    every_frame = AxesMeeting(SETUP, spacing_mm=0.0)
    assert any(every_frame.add(line) for line in _pose_locked_lines(INSERTION, helix_tips(3000), 0))
    assert every_frame.lines < 200


@pytest.mark.parametrize("frames", [40, 3000])
def test_the_same_session_about_an_insertion_point_half_a_mm_away_is_caught(frames: int) -> None:
    meeting = AxesMeeting(SETUP)
    pivot = INSERTION + np.array([0.5, 0.0, 0.0])
    assert any(meeting.add(line) for line in _pose_locked_lines(pivot, helix_tips(frames), 0))
    assert "insertion point" in meeting.verdict


def test_a_still_hand_adds_one_pose_however_long_it_holds() -> None:
    """3000 frames within a tremor's 0.05 mm of one tip: one line heard, and :meth:`AxesMeeting.is_new` says no
    before the free fit is paid for; a tip a spacing away is new."""
    rng = np.random.default_rng(0)
    tips = np.array([1.0, 0.5, 4.0]) + rng.uniform(-0.05, 0.05, (3000, 3))
    meeting = AxesMeeting(SETUP)
    for tip, line in zip(tips, _pose_locked_lines(INSERTION, tips, 1), strict=True):
        meeting.add(line, pose_tip=tip)
    assert meeting.lines == 1 and not meeting.is_new(tips[0] + 0.9 * POSE_SPACING_MM * normalize(np.ones(3)))
    assert meeting.is_new(tips[0] + 1.2 * POSE_SPACING_MM * np.array([0.0, 0.0, 1.0]))


@pytest.mark.slow  # 1000 frames rendered and tracked at 512 px (a few minutes): make test-all
def test_a_ten_second_tracked_session_from_its_own_setup_is_never_flagged() -> None:
    """The issue's false alarm: the helix in 1000 frames (10 s at 100 fps), 512 px, one beam, rendered from the
    setup that tracks it. Heard a frame at a time (``AxesMeeting(SETUP, spacing_mm=0.0)``), the test spoke 59
    frames in (0.51 mm, 6 sigma) and 58 frames were ``ok``; a pose at a time, at least 98 % are and it never
    speaks."""
    renderer, tracker = Renderer(SETUP), Tracker(SETUP)
    poses = [InstrumentPose.through_insertion(tip, INSERTION) for tip in helix_tips(1000)]
    answered = sum(tracker.update(renderer.render(pose, seed=i)).estimate.ok for i, pose in enumerate(poses))
    assert not tracker.sequence.verdict and answered >= 980, (answered, tracker.sequence.verdict)
    assert MIN_LINES < tracker.sequence.lines < 100
