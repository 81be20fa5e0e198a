from __future__ import annotations

import gc
import time
from pathlib import Path

import numpy as np
import pytest
from test_cli import write_scene

from spotnav.app import session
from spotnav.app.sequence_render import render_sequence
from spotnav.app.session import TrackLimits, TrackSession, camera_settings, compiling_note
from spotnav.app.track import TrackedFrame, Tracker
from spotnav.errors import SpotnavError
from spotnav.files.setup_files import read_setup


def test_a_slow_start_says_so(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(session, "SLOW_START_S", 0.01)
    with compiling_note():
        time.sleep(0.2)
    assert "preparing the numerical kernels for this kind of frame, once" in capsys.readouterr().err
    with compiling_note():
        pass
    time.sleep(0.05)
    assert capsys.readouterr().err == ""  # a quick start says nothing


def test_a_session_runs_its_loop_with_the_heap_frozen(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # A full garbage collection walks every object alive; the tracking loop leaves those alive before it to themselves
    # (spotnav.app.track.frozen_heap) and gives them back after.
    setup = read_setup(write_scene(tmp_path / "setup.toml", size_px=256, blend=0.15))
    frames = tmp_path / "frames"
    render_sequence(setup, "helix", frames, frames=12, fps=100.0, tremor_mm=0.0, seed=0)
    frozen, update = [], Tracker.update

    def counting_update(self: Tracker, image: np.ndarray) -> TrackedFrame:
        frozen.append(gc.get_freeze_count())
        return update(self, image)

    monkeypatch.setattr(Tracker, "update", counting_update)
    result = TrackSession(setup, str(frames), tmp_path / "poses.csv", limits=TrackLimits(max_frames=3)).run()
    assert len(frozen) == 3 and min(frozen) > 100_000 and gc.get_freeze_count() == 0
    assert result.rows == 3 and result.stop == "--max-frames 3" and len(result.latencies) == 3
    assert not result.wrong_size_stop


@pytest.mark.parametrize(
    ("limits", "camera", "message"),
    [
        ({"max_frames": 0}, {}, "--max-frames must be at least 1"),
        ({"duration_s": float("nan")}, {}, "--duration must be a finite number of seconds > 0"),
        ({}, {"size_px": (0, 10)}, "--camera-size must be positive"),
        ({}, {"fps": 0.0}, "--fps must be a finite number > 0"),
        ({}, {"exposure": float("inf")}, "--exposure must be a finite number"),
    ],
)
def test_unusable_limits_and_camera_settings_are_user_errors(
    limits: dict[str, float], camera: dict[str, object], message: str
) -> None:
    with pytest.raises(SpotnavError, match=message):
        TrackLimits(**limits)
        camera_settings(camera.get("size_px"), camera.get("fps"), camera.get("exposure"))
