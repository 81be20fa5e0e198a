from __future__ import annotations

import csv
import gc
import itertools
import json
import math
import os
import signal
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import SteppedClock
from test_cli import write_scene
from test_igtl import free_port, recording_client, wait_for

from spotnav.app import session
from spotnav.app.igtl import DEFAULT_DEVICE
from spotnav.app.sequence_render import render_sequence
from spotnav.app.session import (
    IgtlSettings,
    TrackLimits,
    TrackSession,
    camera_settings,
    compiling_note,
    replay_speed,
)
from spotnav.app.track import TrackedFrame, Tracker
from spotnav.errors import SpotnavError
from spotnav.files import recording
from spotnav.files.capture import Frame
from spotnav.files.images import write_image
from spotnav.files.recording import FRAMES_CSV, SETUP_TOML, RecordingWriter
from spotnav.files.sequences import CameraSettings, iter_frames
from spotnav.files.setup_files import read_setup
from spotnav.setup.config import Setup

START_S = 1_800_000_000.0  # a capture time, Unix seconds


def test_a_slow_start_says_so(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(session, "SLOW_START_S", 0.01)
    with compiling_note():
        time.sleep(0.2)
    assert "preparing the numerical kernels for this kind of frame, once" in capsys.readouterr().err
    with compiling_note():
        pass
    time.sleep(0.05)
    assert capsys.readouterr().err == ""  # a quick start says nothing


def test_a_signal_ends_the_run_after_the_frame_in_hand_with_exit_130(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Issue 61: one exit for an interrupt, whatever the source: the rows finished, the signal named, exit 130.
    setup = read_setup(write_scene(tmp_path / "setup.toml", size_px=256, blend=0.15))
    frames = tmp_path / "frames"
    render_sequence(setup, "helix", frames, frames=12, fps=100.0, tremor_mm=0.0, seed=0)
    update, seen = Tracker.update, []

    def interrupted_update(self: Tracker, image: np.ndarray) -> TrackedFrame:
        seen.append(image)
        tracked = update(self, image)
        if len(seen) == 3:
            os.kill(os.getpid(), signal.SIGINT)  # while the third frame is in hand
        return tracked

    monkeypatch.setattr(Tracker, "update", interrupted_update)
    result = TrackSession(setup, str(frames), tmp_path / "poses.csv").run()
    assert (result.rows, result.signal, result.stop, result.exit_code) == (3, "SIGINT", "stopped by SIGINT", 130)
    with (tmp_path / "poses.csv").open() as handle:
        assert [row["frame"] for row in csv.DictReader(handle)] == ["0", "1", "2"]
    assert result.summary().startswith("3 frames, ") and result.summary().endswith("(stopped by SIGINT)")


def test_an_interrupt_while_the_tracker_starts_ends_the_run_at_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Issue 61: the tracker's start (its kernels loaded and rehearsed: seconds on a busy machine) went on after a
    # Ctrl-C, then the run ended with "0 frames". Now an interrupt then ends it at once, before the source is opened
    # (here a video that does not exist) or poses.csv written: the command line leaves the header and exits 130.
    setup = read_setup(write_scene(tmp_path / "setup.toml", size_px=256, blend=0.15))
    start = Tracker.__init__

    def interrupted_start(self: Tracker, *args: object, **kwargs: object) -> None:
        start(self, *args, **kwargs)  # type: ignore[arg-type]
        os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(Tracker, "__init__", interrupted_start)
    with pytest.raises(KeyboardInterrupt):
        TrackSession(setup, str(tmp_path / "none.mkv"), tmp_path / "poses.csv").run()
    assert not (tmp_path / "poses.csv").exists()


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


@pytest.fixture(scope="module")
def helix(tmp_path_factory: pytest.TempPathFactory) -> tuple[Setup, Path]:
    """A 200-frame helix at 256 px, a 100 fps FFV1 video, and its setup."""
    folder = tmp_path_factory.mktemp("helix")
    setup = read_setup(write_scene(folder / "setup.toml", size_px=256, blend=0.15))
    render_sequence(setup, "helix", folder / "helix.mkv", frames=200, fps=100.0, tremor_mm=0.0, seed=0)
    return setup, folder / "helix.mkv"


def read_rows(path: Path) -> list[dict[str, str]]:
    with path.open() as handle:
        return list(csv.DictReader(handle))


def test_a_recorded_session_replays_to_the_same_poses_with_the_recorded_capture_times(
    helix: tuple[Setup, Path], tmp_path: Path
) -> None:
    setup, video = helix
    said: list[str] = []
    live = TrackSession(setup, str(video), tmp_path / "live.csv", record=tmp_path / "rec", report=said.append).run()
    assert live.rows == 200 and live.statuses["ok"] >= 150  # 256 px: most frames answered
    recorded = [line for line in said if line.startswith("recorded ")]
    assert recorded and recorded[0].startswith(f"recorded 200 frames in {tmp_path / 'rec'}: ")
    before = time.time()
    replay = TrackSession(setup, str(tmp_path / "rec"), tmp_path / "replay.csv", replay_speed=math.inf).run()
    assert replay.rows == 200
    first, again = read_rows(tmp_path / "live.csv"), read_rows(tmp_path / "replay.csv")
    timing = {"latency_ms", "decode_ms"}
    assert [{k: v for k, v in row.items() if k not in timing} for row in again] == [
        {k: v for k, v in row.items() if k not in timing} for row in first
    ]  # every pose, status, mode and timestamp_s, to the last digit
    frames = read_rows(tmp_path / "rec" / FRAMES_CSV)
    assert [r["timestamp_s"] for r in frames] == [r["timestamp_s"] for r in again]
    assert len(set(r["timestamp_s"] for r in again)) == 200  # the capture times, not the replay's
    assert float(again[-1]["timestamp_s"]) < before
    assert read_setup(tmp_path / "rec" / SETUP_TOML) == setup


def test_a_replay_at_the_recorded_pace_takes_the_recorded_time(
    helix: tuple[Setup, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    setup, video = helix
    with RecordingWriter(tmp_path / "rec", "") as writer:  # six frames 0.1 s apart: 0.5 s
        for frame in itertools.islice(iter_frames(str(video)), 6):
            writer.add(replace(frame, timestamp_s=START_S + 0.1 * frame.index))
    clock = SteppedClock()  # issue 61: the replay's schedule, on a clock that moves only when the replay waits
    monkeypatch.setattr(recording, "time", clock)
    arrived, update = [], Tracker.update

    def timed_update(self: Tracker, image: np.ndarray) -> TrackedFrame:
        arrived.append(clock.perf_counter())
        return update(self, image)

    monkeypatch.setattr(Tracker, "update", timed_update)
    for speed, span_s in ((1.0, 0.5), (2.0, 0.25)):
        arrived.clear()
        result = TrackSession(setup, str(tmp_path / "rec"), tmp_path / "poses.csv", replay_speed=speed).run()
        gaps = np.diff(arrived)  # the recorded times are Unix seconds: 0.2 us apart at best
        assert result.rows == 6 and gaps == pytest.approx(np.full(5, span_s / 5), abs=1e-6)
        stamps = [float(r["timestamp_s"]) for r in read_rows(tmp_path / "poses.csv")]
        assert stamps == pytest.approx(START_S + 0.1 * np.arange(6), abs=1e-6)


def test_the_overlay_is_written_at_the_source_s_frame_rate(helix: tuple[Setup, Path], tmp_path: Path) -> None:
    setup, video = helix
    frames = list(itertools.islice(iter_frames(str(video)), 3))
    with RecordingWriter(tmp_path / "rec", "") as writer:  # a 50 fps recording
        for frame in frames:
            writer.add(replace(frame, timestamp_s=START_S + 0.02 * frame.index))
    for frame in frames:
        write_image(tmp_path / "images" / f"frame_{frame.index:05d}.png", frame.pixels)  # type: ignore[arg-type]
    cases = [  # source, the fps asked for, the overlay's fps, the note
        (str(video), None, 100.0, False),
        (str(video), 25.0, 100.0, False),  # the source's own rate comes first
        (str(tmp_path / "rec"), None, 50.0, False),
        (str(tmp_path / "images"), 25.0, 25.0, False),
        (str(tmp_path / "images"), None, 30.0, True),
    ]
    for number, (source, fps, expected, noted) in enumerate(cases):
        said: list[str] = []
        overlay = tmp_path / f"overlay{number}.mkv"
        limits = TrackLimits(max_frames=3)
        camera = CameraSettings(fps=fps)
        TrackSession(setup, source, tmp_path / "poses.csv", limits=limits, camera=camera, overlay=overlay,
                     report=said.append).run()  # fmt: skip
        capture = cv2.VideoCapture(str(overlay))
        assert capture.get(cv2.CAP_PROP_FPS) == pytest.approx(expected, rel=1e-3), source
        assert capture.get(cv2.CAP_PROP_FRAME_COUNT) == 3
        capture.release()
        note = f"spotnav: note: {source} has no frame rate: the overlay is written at 30 fps (--fps F)"
        assert (note in said) == noted


def test_a_stalled_source_turns_the_openigtlink_pose_invalid_until_its_next_frame(
    helix: tuple[Setup, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    setup, video = helix
    middle = itertools.islice(iter_frames(str(video)), 100, 108)  # frames that are answered
    kept = [replace(f, index=f.index - 100, pixels=f.pixels.copy()) for f in middle]  # type: ignore[union-attr]
    stalled_at: list[float] = []

    def stalling_source(*_: object, **__: object) -> Iterator[Frame]:
        for frame in kept:
            if frame.index == 5:  # frames 0-4, one second without a frame, then 5-7
                stalled_at.append(time.monotonic())
                time.sleep(1.0)
            yield replace(frame, ready_s=time.perf_counter(), timestamp_s=time.time())

    monkeypatch.setattr(session, "iter_frames", stalling_source)
    port = free_port()
    with recording_client(port) as messages:
        igtl = IgtlSettings(port, wait_s=10.0, stale_s=0.5)
        result = TrackSession(setup, str(video), tmp_path / "poses.csv", igtl=igtl).run()
        assert wait_for(lambda: any(json.loads(m.string)["frame"] == 7 for m in messages.of(DEFAULT_DEVICE + "Status")))
    rows = read_rows(tmp_path / "poses.csv")
    assert result.rows == 8 and rows[4]["status"] == rows[5]["status"] == "ok"  # the poses around the stall
    transforms = messages.timed(DEFAULT_DEVICE)
    statuses = [json.loads(m.string) for m in messages.of(DEFAULT_DEVICE + "Status")]
    stale = len(transforms) - 8  # stale at 0.5 s, and again every 0.5 s while the stall (and a busy machine) lasts
    assert stale >= 1 and len(statuses) == len(transforms)
    assert [s["status"] for s in statuses] == [r["status"] for r in rows[:5]] + ["stale"] * stale + [
        r["status"] for r in rows[5:]
    ]
    for (_, transform), status in zip(transforms, statuses, strict=True):
        assert transform.metadata["TransformStatus"] == ("OK" if status["status"] == "ok" else "INVALID")
    last_ok, invalid, next_ok = transforms[4][0], transforms[5][0], transforms[5 + stale][0]
    assert invalid - last_ok >= 0.45 and invalid > stalled_at[0]  # INVALID after 0.5 s without a frame
    assert transforms[5][1].metadata["Status"] == "stale" and statuses[5]["frame"] == 4
    assert statuses[5]["seconds_since_frame"] >= 0.5 and statuses[5]["detail"].startswith("no frame for ")
    assert next_ok - stalled_at[0] >= 1.0 and statuses[5 + stale]["frame"] == 5  # OK again with the next frame


def test_replay_speed_is_fast_or_a_factor_of_the_recorded_pace() -> None:
    assert replay_speed("fast") == math.inf and replay_speed("1") == 1.0 and replay_speed("2.5") == 2.5
    for wrong in ("0", "-1", "slow", "nan", "inf"):
        with pytest.raises(SpotnavError, match="--replay-speed must be fast or a number > 0"):
            replay_speed(wrong)


def test_a_wrong_size_frame_is_lost_to_the_tracker_live_and_in_its_replay(tmp_path: Path) -> None:
    # Review: a video's wrong-size frame went through the tracker (lost: it forgets its prediction) while a file's,
    # or the same frame replayed from a recording, skipped it, so a replay's modes could differ from the session's.
    setup = read_setup(write_scene(tmp_path / "setup.toml", size_px=256, blend=0.15))
    render_sequence(setup, "helix", tmp_path / "frames", frames=200, fps=100.0, tremor_mm=0.0, seed=0)
    pngs = sorted((tmp_path / "frames").glob("*.png"))
    write_image(pngs[100], np.zeros((128, 128, 3), np.uint8))
    TrackSession(setup, str(tmp_path / "frames"), tmp_path / "live.csv", record=tmp_path / "rec").run()
    TrackSession(setup, str(tmp_path / "rec"), tmp_path / "replay.csv", replay_speed=math.inf).run()
    live, again = read_rows(tmp_path / "live.csv"), read_rows(tmp_path / "replay.csv")
    assert (live[100]["status"], live[100]["mode"]) == ("wrong_size", "lost")
    assert live[99]["mode"] == "tracked" and live[101]["mode"] == "reacquired"  # read anew where it was last seen
    assert [(r["status"], r["mode"], r["x_mm"]) for r in again] == [(r["status"], r["mode"], r["x_mm"]) for r in live]
