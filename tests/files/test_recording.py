from __future__ import annotations

import contextlib
import csv
import math
import os
import shutil
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import SteppedClock

from spotnav.errors import InputError
from spotnav.files.capture import Frame
from spotnav.files.recording import (
    FRAMES_CSV,
    RECORDING_COLUMNS,
    SETUP_TOML,
    RecordingWriter,
    is_recording,
    read_recording,
    recording_fps,
)
from spotnav.files.sequences import iter_frames

START_S = 1_800_000_000.0  # a capture time, Unix seconds


def frames(count: int, interval_s: float = 0.01, shape: tuple[int, ...] = (24, 32, 3)) -> list[Frame]:
    """Frames of distinct random pixels (16-bit when ``shape`` is 2-D), captured every ``interval_s``."""
    rng = np.random.default_rng(1)
    dtype = np.uint16 if len(shape) == 2 else np.uint8
    made = []
    for index in range(count):
        pixels = rng.integers(0, np.iinfo(dtype).max, size=shape, endpoint=True).astype(dtype)
        made.append(Frame(index, "", pixels, 0.0, 0.0, timestamp_s=START_S + index * interval_s))
    return made


def record(folder: Path, kept: list[Frame], **options: object) -> RecordingWriter:
    with RecordingWriter(folder, "[eye]\nradius_mm = 12.5\n", **options) as writer:  # type: ignore[arg-type]
        for frame in kept:
            writer.add(frame)
    return writer


@pytest.mark.parametrize("shape", [(24, 32, 3), (24, 32)], ids=["rgb8", "grey16"])
def test_a_recording_replays_every_frame_bit_for_bit_with_its_capture_time(
    tmp_path: Path, shape: tuple[int, ...]
) -> None:
    kept = frames(6, shape=shape)
    reused = kept[0].pixels
    assert reused is not None
    unreadable = Frame(6, "frame_6.png", None, 0.0, 0.0, "frame_6.png: the file is empty", START_S + 0.06)
    writer = record(tmp_path / "rec", [*kept, unreadable])
    reused[:] = 0  # a source reuses its buffers: the recording kept a copy
    assert writer.frames == 7 and writer.copy_s > 0 and writer.write_s > 0
    assert is_recording(str(tmp_path / "rec")) and (tmp_path / "rec" / SETUP_TOML).read_text().startswith("[eye]")
    with (tmp_path / "rec" / FRAMES_CSV).open() as handle:
        rows = list(csv.DictReader(handle))
    assert tuple(rows[0]) == RECORDING_COLUMNS and [r["file"] for r in rows[-2:]] == ["frame_00005.png", ""]
    replayed = list(read_recording(tmp_path / "rec", speed=math.inf))
    assert [f.index for f in replayed] == list(range(7))
    assert [f.timestamp_s for f in replayed] == pytest.approx([START_S + 0.01 * i for i in range(7)], abs=1e-6)
    for original, frame in zip(frames(6, shape=shape), replayed, strict=False):
        assert frame.pixels is not None and frame.pixels.dtype == original.pixels.dtype  # type: ignore[union-attr]
        np.testing.assert_array_equal(frame.pixels, original.pixels)
    last = replayed[-1]
    assert last.pixels is None and last.error == unreadable.error and last.image == "frame_6.png"


def test_a_replay_keeps_the_recorded_pace_and_scales_it(tmp_path: Path, replay_clock: SteppedClock) -> None:
    # Issue 61: the schedule on a clock that moves only when the replay waits, not the machine's seconds.
    record(tmp_path / "rec", frames(6, interval_s=0.1))  # 0.5 s from the first frame to the last
    for speed, span_s in ((1.0, 0.5), (2.0, 0.25), (math.inf, 0.0)):
        arrived = [frame.ready_s for frame in read_recording(tmp_path / "rec", speed=speed)]
        assert np.diff(arrived) == pytest.approx(np.full(5, span_s / 5), abs=1e-6)  # Unix seconds hold 0.2 us
    waits = len(replay_clock.slept)
    asked_to_stop = [f.ready_s for f in read_recording(tmp_path / "rec", speed=1.0, stop=lambda: True)]
    assert asked_to_stop[-1] == asked_to_stop[0] and len(replay_clock.slept) == waits  # a stop does not wait


def test_a_recording_s_frame_rate_comes_from_its_timestamps_and_iter_frames_replays_it(tmp_path: Path) -> None:
    kept = frames(8, interval_s=0.01)
    stalled = [Frame(f.index, "", f.pixels, 0.0, 0.0, timestamp_s=f.timestamp_s + (1.0 if f.index > 4 else 0.0))
               for f in kept]  # fmt: skip
    record(tmp_path / "rec", stalled)
    assert recording_fps(tmp_path / "rec") == 100.0  # a stall does not slow it
    rates: list[float] = []
    replayed = list(iter_frames(str(tmp_path / "rec"), fps=rates.append))
    assert rates == [100.0] and len(replayed) == 8 and replayed[5].timestamp_s == pytest.approx(START_S + 1.05)
    record(tmp_path / "one", frames(1))
    assert recording_fps(tmp_path / "one") is None


@contextlib.contextmanager
def stalled(writer: RecordingWriter, seconds: float) -> Iterator[None]:
    """The writing process stopped (a disk that does not answer) for ``seconds`` from now."""
    os.kill(writer.process.pid, signal.SIGSTOP)
    again = threading.Timer(seconds, os.kill, (writer.process.pid, signal.SIGCONT))
    again.start()
    try:
        yield
    finally:
        again.join()


def test_a_slow_disk_keeps_every_frame_and_says_so_once(tmp_path: Path) -> None:
    said: list[str] = []
    kept = frames(20)
    size = 2 * kept[0].pixels.nbytes  # type: ignore[union-attr]
    start = time.perf_counter()
    with RecordingWriter(tmp_path / "rec", "", max_pending_bytes=size, report=said.append) as writer:
        with stalled(writer, 0.4):
            for frame in kept:
                writer.add(frame)
    assert time.perf_counter() - start >= 0.4  # add waited for the disk
    assert writer.frames == 20 and len(list((tmp_path / "rec").glob("frame_*.png"))) == 20
    assert len(said) == 1 and "the disk is behind: tracking waits for it" in said[0]
    assert writer.wait_s > 0 and writer.copy_s > 0  # the caller waited for the disk, apart from copying
    said.clear()
    with RecordingWriter(tmp_path / "more", "", report=said.append) as writer:  # room for every frame: none waits
        with stalled(writer, 0.4):
            for frame in frames(30):
                writer.add(frame)
            writer.close()  # while the disk is stalled
    assert writer.frames == 30 and writer.wait_s == 0
    assert said == [f"{tmp_path / 'more'}: writing the 30 frames still in memory ..."]
    assert len(list((tmp_path / "more").glob("frame_*.png"))) == 30


def test_the_writing_process_keeps_off_the_tracker_s_core_at_a_lower_priority(tmp_path: Path) -> None:
    cores = os.sched_getaffinity(0)
    if len(cores) < 2:
        pytest.skip("one core: nothing to keep off")
    own = {min(cores)}
    try:
        os.sched_setaffinity(0, own)  # as a video's decoder keeps the tracker's thread
        with RecordingWriter(tmp_path / "rec", "") as writer:
            writer.add(frames(1)[0])
            assert os.sched_getaffinity(writer.process.pid) == cores - own
            assert os.getpriority(os.PRIO_PROCESS, writer.process.pid) > os.getpriority(os.PRIO_PROCESS, 0)
    finally:
        os.sched_setaffinity(0, cores)
    assert writer.frames == 1


def test_recordings_that_cannot_be_used_are_user_errors(tmp_path: Path) -> None:
    record(tmp_path / "rec", frames(2))
    with pytest.raises(InputError, match="holds a recording already"):
        RecordingWriter(tmp_path / "rec", "")
    with pytest.raises(InputError, match="--replay-speed must be fast or a number > 0"):
        read_recording(tmp_path / "rec", speed=0.0)
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / FRAMES_CSV).write_text("frame,file,timestamp_s\n0,frame_00000.png,yesterday\n")
    with pytest.raises(InputError, match="line 2: frame must be an integer and timestamp_s a number"):
        read_recording(tmp_path / "bad")
    (tmp_path / "bad" / FRAMES_CSV).write_text("frame,image\n")
    with pytest.raises(InputError, match=r"no column file, timestamp_s: not a recording's frames\.csv"):
        read_recording(tmp_path / "bad")


@pytest.mark.parametrize("failure", ["raises", "refuses", "killed"])
def test_a_frame_that_cannot_be_written_stops_the_recording_and_says_so(tmp_path: Path, failure: str) -> None:
    # Review: an encoder that raised killed the writer silently, and add then waited forever for memory the writer
    # would never give back; a write that failed on the last frames was never told.
    kept = frames(8)
    writer = RecordingWriter(tmp_path / "rec", "", max_pending_bytes=kept[0].pixels.nbytes)  # type: ignore[union-attr]
    if failure == "raises":  # two channels: OpenCV's PNG encoder raises
        kept = [Frame(f.index, "", np.zeros((24, 32, 2), np.uint8), 0.0, 0.0) for f in kept]
    elif failure == "refuses":  # the folder is gone: OpenCV returns False
        shutil.rmtree(tmp_path / "rec")
    else:
        os.kill(writer.process.pid, signal.SIGKILL)
    with pytest.raises(InputError, match="recording stopped"):
        for frame in kept:  # at most one frame waits in memory: add must not wait forever
            writer.add(frame)
    with pytest.raises(InputError, match="recording stopped after 0 frames"):
        writer.close()
    if failure == "killed":
        assert "its writing process ended (exit code -9)" in str(writer.error)
