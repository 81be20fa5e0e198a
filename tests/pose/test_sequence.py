from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import small_setup
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav.app.track import Tracker
from spotnav.optics.render import Renderer
from spotnav.pose.sequence import MEETING_SIGMAS, MIN_LINES, AxesMeeting, AxisLine
from spotnav.setup.geometry import InstrumentPose, normalize

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
