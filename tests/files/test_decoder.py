from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from spotnav.files import decoder
from spotnav.files.capture import Frame
from spotnav.files.images import ImageReadError
from spotnav.files.sequences import SequenceWriter, iter_frames


def _clip(tmp_path: Path, count: int, shape: tuple[int, int] = (48, 64)) -> tuple[Path, list[np.ndarray]]:
    """An FFV1 clip of ``count`` noise frames of ``shape`` (rows, columns), and the frames."""
    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 256, (*shape, 3), dtype=np.uint8) for _ in range(count)]
    with SequenceWriter(tmp_path / "clip.mkv", fps=30.0) as writer:
        for index, rgb in enumerate(frames):
            writer.write(index, rgb)
    return tmp_path / "clip.mkv", frames


@pytest.mark.parametrize("ring", [0, 2])
def test_video_frames_decode_exactly_and_a_ring_reuses_its_buffers(tmp_path: Path, ring: int) -> None:
    clip, frames = _clip(tmp_path, 4)
    decoded = []
    for frame in iter_frames(str(clip), ring=ring):
        np.testing.assert_array_equal(frame.pixels, frames[frame.index])  # lossless, as handed over
        decoded.append(frame.pixels)
    assert len(decoded) == 4
    assert (decoded[0] is decoded[2]) == (ring == 2) and decoded[0] is not decoded[1]


def _child_processes() -> set[str]:
    return {
        child
        for task in Path(f"/proc/{os.getpid()}/task").iterdir()
        for child in (task / "children").read_text().split()
    }


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads Linux's /proc")
def test_a_decoder_process_hands_over_every_frame_and_keeps_the_one_before(tmp_path: Path) -> None:
    clip, frames = _clip(tmp_path, 7)
    cores, before = os.sched_getaffinity(0), _child_processes()
    waited_on: list[np.ndarray] = []
    source = iter_frames(str(clip), ring=2, while_waiting=waited_on.append)
    handed: list[Frame] = []
    for index in range(7):
        asked, waits = time.perf_counter(), len(waited_on)
        frame = next(source)
        # Asked for 50 ms after the frame before, once the decoder had it: its latency starts when it is asked for.
        assert frame.index == index and asked <= frame.ready_s <= time.perf_counter() and frame.decode_ms > 0
        np.testing.assert_array_equal(frame.pixels, frames[index])  # lossless, as handed over
        assert all(pixels is handed[-1].pixels for pixels in waited_on[waits:])  # it rehearsed the frame before
        time.sleep(0.05)  # the decoder has decoded the next frame meanwhile, into a buffer of its own
        if handed:  # the frame before is not written over: a rehearsal reads it
            np.testing.assert_array_equal(handed[-1].pixels, frames[index - 1])
        assert len(os.sched_getaffinity(0)) == (1 if len(cores) > 1 else len(cores))  # this thread on one core
        assert len(_child_processes() - before) == (1 if len(cores) > 1 else 0)
        handed.append(frame)
    with pytest.raises(StopIteration):
        next(source)
    assert np.shares_memory(handed[0].pixels, handed[3].pixels) == (len(cores) > 1)  # a ring of three buffers
    assert not np.shares_memory(handed[0].pixels, handed[1].pixels)
    assert os.sched_getaffinity(0) == cores and _child_processes() == before


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads Linux's /proc")
def test_a_decoder_process_stops_with_its_reader_and_reports_its_failure(tmp_path: Path) -> None:
    clip, frames = _clip(tmp_path, 5)
    cores, before = os.sched_getaffinity(0), _child_processes()
    source = iter_frames(str(clip), ring=1, while_waiting=lambda pixels: None)
    np.testing.assert_array_equal(next(source).pixels, frames[0])
    source.close()
    assert os.sched_getaffinity(0) == cores and _child_processes() == before

    def failing(pixels: np.ndarray) -> None:
        raise RuntimeError("a rehearsal failed")

    # Frames that take milliseconds to decode: the next one is surely still being decoded when it is asked for,
    # and the rehearsal runs (a frame already there is handed over without one).
    slow, _ = _clip(tmp_path / "slow", 2, (1024, 1024))
    source = iter_frames(str(slow), ring=2, while_waiting=failing)
    next(source)
    with pytest.raises(RuntimeError, match="a rehearsal failed"):
        next(source)
    assert os.sched_getaffinity(0) == cores and _child_processes() == before
    source = iter_frames(str(clip), ring=2, while_waiting=lambda pixels: None)  # opened and checked here ...
    clip.unlink()  # ... then gone when the decoder opens it
    with pytest.raises(ImageReadError, match=r"clip\.mkv: the decoder process failed: .*no such file"):
        next(source)
    assert os.sched_getaffinity(0) == cores and _child_processes() == before
    with pytest.raises(ValueError, match="ring must be at least 1, got 0"):
        next(iter_frames(str(tmp_path), ring=0, while_waiting=lambda pixels: None))


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads Linux's /proc")
def test_without_shared_memory_or_a_second_core_a_video_is_decoded_in_this_thread(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    clip, frames = _clip(tmp_path, 3)

    def no_room(descriptor: int, offset: int, size: int) -> None:
        raise OSError(28, "No space left on device")

    before = _child_processes()
    for patch in [(os, "posix_fallocate", no_room), (os, "sched_getaffinity", lambda pid: {0})]:
        with monkeypatch.context() as patched:
            patched.setattr(*patch)
            for frame in iter_frames(str(clip), ring=2, while_waiting=lambda pixels: None):
                np.testing.assert_array_equal(frame.pixels, frames[frame.index])
                assert _child_processes() == before  # no decoder process


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads Linux's /proc")
def test_the_tracker_keeps_to_the_core_it_runs_on() -> None:
    # Two trackers on one machine each keep to the core the scheduler gave it, not both to the first one.
    cores = os.sched_getaffinity(0)
    try:
        for core in sorted(cores):
            os.sched_setaffinity(0, {core})
            assert decoder._current_core(cores) == core
    finally:
        os.sched_setaffinity(0, cores)
    assert decoder._current_core(set(range(10_000, 10_002))) == 10_000  # a core it may not run on: the first allowed
    own, others = decoder._split_cores()
    assert (len(own), own | others, own & others) == ((1, cores, set()) if len(cores) > 1 else (0, set(), set()))


@pytest.mark.skipif(
    not Path("/proc/self/task").is_dir() or len(os.sched_getaffinity(0)) < 2, reason="a decoder process: Linux, 2 cores"
)
def test_a_stop_ends_a_decoder_s_frames_and_the_decoder(tmp_path: Path) -> None:
    # Issue 61: Ctrl-C as track started waited for the decoder process to start and decode a frame no one would
    # track, then for it to end. Now a stop ends the frames while one is awaited, and the decoder with them.
    clip, _ = _clip(tmp_path, 6)
    before, stopped = _child_processes(), list[bool]()
    source = iter_frames(str(clip), ring=2, while_waiting=lambda pixels: None, stop=lambda: bool(stopped))
    assert [next(source).index, next(source).index] == [0, 1]
    stopped.append(True)
    with pytest.raises(StopIteration):
        next(source)
    assert _child_processes() == before
    asked: list[bool] = []  # a stop before the first frame: none, and the decoder (still starting) is not waited for
    source = iter_frames(str(clip), ring=2, while_waiting=lambda pixels: None, stop=lambda: asked.append(True) is None)
    assert list(source) == [] and asked == [True] and _child_processes() == before
