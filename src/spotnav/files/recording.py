"""A tracking session's recording: every frame kept losslessly with its capture time, and replayed at its pace.

A recording is a folder:

- ``frame_00000.png``, ... : each frame as the source gave it (grey or RGB, 8 or 16 bits), lossless PNG;
- ``frames.csv`` (:data:`RECORDING_COLUMNS`): ``frame`` (the source's index), ``file`` (the PNG, empty for a frame
  the source could not give), ``timestamp_s`` (the capture time, Unix seconds), ``image`` (the source's image file,
  empty for a video or camera frame), ``error_status`` and ``error`` (why a frame has no PNG);
- ``setup.toml``: the setup the session tracked with.

:class:`RecordingWriter` copies each frame into shared memory in the caller's thread (its only cost there) and a
process of its own writes it, in order, each row of ``frames.csv`` on disk once its PNG is: that process runs at a
lower priority than the tracker and off the tracker's core (when a video's decoder keeps the tracker to one), and
shares neither its interpreter lock nor its memory's bookkeeping. :func:`read_recording` replays a recording
as a sequence of :class:`~spotnav.files.capture.Frame` at its original pace (or faster), each stamped with its
recorded capture time.
"""

from __future__ import annotations

import contextlib
import csv
import math
import mmap
import os
import pickle
import select
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Generator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import cv2
import numpy as np

from spotnav.errors import InputError
from spotnav.files.capture import Frame
from spotnav.files.images import ImageReadError, read_image
from spotnav.files.numbers import parse_float, parse_int
from spotnav.files.processes import shared_memory, start_python

__all__ = [
    "FRAMES_CSV",
    "MAX_PENDING_BYTES",
    "RECORDING_COLUMNS",
    "SETUP_TOML",
    "RecordingWriter",
    "is_recording",
    "read_recording",
    "recording_fps",
    "write_recording_main",
]

FRAMES_CSV = "frames.csv"
SETUP_TOML = "setup.toml"
RECORDING_COLUMNS = ("frame", "file", "timestamp_s", "image", "error_status", "error")
MAX_PENDING_BYTES = 1 << 30  # frames copied but not written yet: beyond this the caller waits for the disk
# PNG as fast as it is written: zlib's Huffman coding only, no row filter. A rendered 2048 px frame (its sensor noise
# is what takes the room) in 85 ms of CPU and 6.1 MB, against OpenCV's default (level 3, adaptive filters) 450 ms and
# 6.7 MB; 512 px in 5.5 ms and 380 kB.
_PNG_OPTIONS = [
    *(cv2.IMWRITE_PNG_COMPRESSION, 1),
    *(cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY),
    *(cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE),
]
_SPARE_BUFFERS = 4  # written frames' buffers kept to copy the next ones into (a fresh one costs its page faults)
_WRITER_MAIN = "spotnav.files.recording:write_recording_main"
# The writing process's niceness: the tracker (and a video's decoder) take a core from it at once, and it has what
# they leave. A thread in the tracker's process instead ran on the tracker's core at the tracker's priority, and
# could hold the interpreter's lock the tracker needed (README, --record, for what each costs).
_WRITER_NICE = 10
_MESSAGE_BYTES = 1 << 16  # the longest message between the tracker and the writing process
_READY, _NO_PIXELS = -2, -1  # the writing process's answers that free no slot: it is ready, a frame without pixels
_JOIN_S = 5.0  # how long a writing process whose socket ended may take to exit
_SAY_LEFT = 20  # closing with this many frames still to write says so
_WAIT_SLICE_S = 0.05  # a replay waiting for a frame's time looks at its stop this often


def is_recording(source: str) -> bool:
    """Whether ``source`` is a recording's folder (it holds :data:`FRAMES_CSV`)."""
    return (Path(source) / FRAMES_CSV).is_file()


class RecordingWriter:
    """Keep every frame of a session, with its capture time, in a new recording folder (see the module's docstring).

    Parameters
    ----------
    folder : str or Path
        The recording's folder; created if needed. It must not hold a recording already.
    setup_toml : str
        The setup the frames are tracked with, as TOML (written as ``setup.toml``).
    max_pending_bytes : int
        Frames copied and not yet written take at most this memory; beyond it :meth:`add` waits for the disk
        (every frame is kept; tracking slows) and ``report`` is told once.
    report : callable, optional
        Takes the one line that says the disk is behind.

    Raises
    ------
    InputError
        If the folder holds a recording already, or cannot be written, or the writing process cannot start.

    Use it as a context manager; leaving it waits until every frame is on disk.

    Attributes
    ----------
    frames : int
        Frames written.
    copy_s : float
        Time :meth:`add` took in the caller's thread to copy the frames, s, in total.
    wait_s : float
        Time :meth:`add` waited for the disk, s, in total.
    write_s : float
        Time the writing process took to encode and write the frames, s, in total.
    process : subprocess.Popen
        The writing process.
    """

    def __init__(
        self,
        folder: str | Path,
        setup_toml: str,
        *,
        max_pending_bytes: int = MAX_PENDING_BYTES,
        report: Callable[[str], None] | None = None,
    ) -> None:
        self.folder = Path(folder)
        if is_recording(str(self.folder)):
            raise InputError(f"{self.folder}: holds a recording already: --record a new folder")
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            (self.folder / SETUP_TOML).write_text(setup_toml, encoding="utf-8")
            (self.folder / FRAMES_CSV).write_text(",".join(RECORDING_COLUMNS) + "\n", encoding="utf-8")
        except OSError as error:
            raise InputError(f"{self.folder}: cannot write the recording: {error.strerror or error}") from None
        self.max_pending_bytes, self.report = max_pending_bytes, report
        self.frames, self.copy_s, self.wait_s, self.write_s = 0, 0.0, 0.0, 0.0
        self.error = ""  # why the writing process stopped writing
        self._said_behind, self._closed, self._kept_off = False, False, False
        self._pending_bytes, self._in_flight = 0, 0  # frames sent and not yet written back
        self._slots: dict[int, _Slot] = {}  # shared memory the frames are copied into, by number
        self._spare: list[int] = []  # slots of frames written, to copy the next ones into
        self._forget: list[int] = []  # slots given back, for the writing process to unmap with the next frame
        self._channel, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            arguments = [str(self.folder), str(theirs.fileno())]
            self.process = start_python(_WRITER_MAIN, arguments, pass_fds=(theirs.fileno(),), start_new_session=True)
        except OSError as error:
            self._channel.close()
            raise InputError(f"{self.folder}: cannot start the recording's writing process: {error}") from None
        finally:
            theirs.close()
        self._take_written(block=True)  # it is ready (its imports done before the first frame), or it says why not
        if self.error:
            self.close()

    def add(self, frame: Frame) -> None:
        """Copy ``frame`` (its buffer may be reused) into shared memory and queue it for the writing process.

        Raises
        ------
        InputError
            If a frame could not be written (the disk is full, the folder gone).
        """
        start = time.perf_counter()
        self._take_written(block=False)
        waited = 0.0
        size = 0 if frame.pixels is None else frame.pixels.nbytes
        if self._pending_bytes + size > max(self.max_pending_bytes, size) and not self.error:
            if not self._said_behind and self.report is not None:
                self._said_behind = True
                self.report(f"spotnav: warning: {self.folder}: the disk is behind: tracking waits for it")
            waiting = time.perf_counter()
            while self._pending_bytes + size > max(self.max_pending_bytes, size) and not self.error:
                self._take_written(block=True)
            waited = time.perf_counter() - waiting
        self._check()
        number, descriptor = -1, list[int]()  # the frame's slot, and a new slot's file descriptor to send along
        if frame.pixels is not None:
            self._keep_off_my_cores()
            number, descriptor = self._slot(frame.pixels.nbytes)
            copy = np.ndarray(frame.pixels.shape, frame.pixels.dtype, buffer=self._slots[number].memory)
            np.copyto(copy, frame.pixels)
            self._pending_bytes += size
        shape, dtype = (None, "") if frame.pixels is None else (frame.pixels.shape, frame.pixels.dtype.str)
        fields = (frame.index, frame.timestamp_s, frame.image, frame.error_status, frame.error)
        waited += self._send(pickle.dumps((number, shape, dtype, fields, self._forget)), descriptor)
        self._forget = []
        self._in_flight += 1
        for opened in descriptor:
            os.close(opened)
        self.wait_s += waited
        self.copy_s += time.perf_counter() - start - waited
        self._check()

    def _check(self) -> None:
        """Raise :class:`InputError` if the writing process stopped writing."""
        if self.error:
            raise InputError(f"{self.folder}: recording stopped: {self.error}")

    def _slot(self, size: int) -> tuple[int, list[int]]:
        """A slot of ``size`` bytes: a spare one (no descriptor), or a new one with its descriptor to send along.

        Raises
        ------
        InputError
            If there is no shared memory left for it.
        """
        for index, number in enumerate(self._spare):
            if self._slots[number].size == size:
                return self._spare.pop(index), []
        descriptor = shared_memory(max(size, 1), "spotnav-recording")
        if descriptor is None:
            raise InputError(f"{self.folder}: no shared memory left for a frame of {size} bytes: recording stopped")
        populate = mmap.MAP_SHARED | getattr(mmap, "MAP_POPULATE", 0)  # its page faults now, not in the copy
        number = max(self._slots, default=-1) + 1
        self._slots[number] = _Slot(mmap.mmap(descriptor, max(size, 1), flags=populate), size)
        return number, [descriptor]

    def _keep_off_my_cores(self) -> None:
        """Once: keep the writing process off the cores this thread is kept to (a video's decoder keeps the
        tracker's thread to one core, from its first frame on), if it is kept to some of them only."""
        if self._kept_off or not hasattr(os, "sched_getaffinity"):
            return
        self._kept_off = True
        mine = os.sched_getaffinity(0)
        others = set(range(os.cpu_count() or 1)) - mine
        if others:
            with contextlib.suppress(OSError):  # none of them allowed here, or the process gone (the next frame says)
                os.sched_setaffinity(self.process.pid, others)

    def _send(self, message: bytes, descriptors: list[int]) -> float:
        """Send ``message`` (and ``descriptors``) to the writing process, taking its answers while its queue is full;
        returns the time waited for it, s."""
        waited = 0.0
        while not self.error:
            try:
                socket.send_fds(self._channel, [message], descriptors, socket.MSG_DONTWAIT)
                break
            except BlockingIOError:
                waiting = time.perf_counter()
                select.select([self._channel], [self._channel], [])
                self._take_written(block=False)
                waited += time.perf_counter() - waiting
            except OSError:  # the process is gone
                self._take_written(block=False)
                self.error = self.error or self._ended()
        return waited

    def _take_written(self, *, block: bool) -> None:
        """Take the writing process's answers: every one there is, after waiting for one if ``block``."""
        while not self._closed:
            try:
                answer = self._channel.recv(_MESSAGE_BYTES, 0 if block else socket.MSG_DONTWAIT)
            except BlockingIOError:
                return
            except OSError:
                answer = b""
            if not answer:  # the process ended: after the last frame it was sent, or before
                if self._in_flight:
                    self._in_flight, self.error = 0, self.error or self._ended()
                return
            number, self.frames, self.write_s, error = pickle.loads(answer)
            self.error = self.error or error
            if number >= 0:
                self._in_flight -= 1
                self._give_back(number)
            elif number == _NO_PIXELS:
                self._in_flight -= 1
            block = False

    def _give_back(self, number: int) -> None:
        """A written frame's slot: kept to copy the next ones into, or unmapped beyond :data:`_SPARE_BUFFERS`."""
        self._pending_bytes -= self._slots[number].size
        if len(self._spare) < _SPARE_BUFFERS:
            self._spare.append(number)
        else:
            self._slots.pop(number).memory.close()
            self._forget.append(number)

    def _ended(self) -> str:
        """Why the writing process stopped answering."""
        try:
            code: int | None = self.process.wait(_JOIN_S)
        except subprocess.TimeoutExpired:
            code = None
        return f"its writing process ended ({'still running' if code is None else f'exit code {code}'})"

    def close(self) -> None:
        """Wait until every queued frame is on disk (saying so when many wait), then let the writing process end.

        Raises
        ------
        InputError
            If a frame could not be written: the recording lacks it and those after it.
        """
        if not self._closed:
            try:
                self._take_written(block=False)
                if self._in_flight >= _SAY_LEFT and self.report is not None:
                    self.report(f"{self.folder}: writing the {self._in_flight} frames still in memory ...")
                with contextlib.suppress(OSError):
                    self._channel.shutdown(socket.SHUT_WR)  # the writing process ends after the last frame
                while self._in_flight > 0:
                    self._take_written(block=True)
                self.process.wait()
            finally:
                self._closed = True
                self._channel.close()
                for slot in self._slots.values():
                    slot.memory.close()
        if self.error:
            raise InputError(f"{self.folder}: recording stopped after {self.frames} frames: {self.error}")

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        try:
            self.close()
        except InputError:
            if kind is None:  # a failure already on its way (Ctrl-C, an error) is the one to tell
                raise


@dataclass(frozen=True)
class _Slot:
    memory: mmap.mmap
    size: int  # bytes of the frames it holds


def write_recording_main() -> None:
    """The writing process's work (started by :class:`RecordingWriter`; its arguments: the recording's folder and
    the file descriptor of its end of a ``SOCK_SEQPACKET`` socket pair).

    It says it is ready, then takes each frame's message (its slot of shared memory, a new slot's file descriptor
    with it, the frame's shape, type and fields, and the slots to unmap), writes the PNG and then the row of
    ``frames.csv``, and answers each with the slot it is done with, the frames written, the seconds taken and why
    it stopped writing (``""``: it did not); after a failure it only answers, so that no memory stays taken. It runs
    at a lower priority than the tracker, and in a session of its own: a Ctrl-C to the tracker does not cut the
    recording short; it ends when the socket does.
    """
    folder, descriptor = Path(sys.argv[1]), int(sys.argv[2])
    with contextlib.suppress(OSError):
        os.nice(_WRITER_NICE)
    channel = socket.socket(fileno=descriptor)
    slots: dict[int, mmap.mmap] = {}
    frames, write_s, error = 0, 0.0, ""
    with contextlib.ExitStack() as stack:
        stack.enter_context(channel)
        try:
            handle: TextIO | None = stack.enter_context((folder / FRAMES_CSV).open("a", newline="", encoding="utf-8"))
        except OSError as failure:
            handle, error = None, f"cannot write {folder / FRAMES_CSV}: {failure.strerror or failure}"
        channel.send(pickle.dumps((_READY, frames, write_s, error)))
        while True:
            try:
                message, descriptors, _, _ = socket.recv_fds(channel, _MESSAGE_BYTES, 1)
            except OSError:  # the tracker is gone without closing its end
                return
            if not message:
                return
            number, shape, dtype, fields, forget = pickle.loads(message)
            for old in forget:
                slots.pop(old).close()
            pixels = None
            if number >= 0:
                if descriptors:
                    slots[number] = mmap.mmap(descriptors[0], max(int(np.prod(shape)) * np.dtype(dtype).itemsize, 1))
                    os.close(descriptors[0])
                pixels = np.ndarray(shape, np.dtype(dtype), buffer=slots[number])
            start = time.perf_counter()
            if not error and handle is not None:
                try:
                    error = _write_frame(folder, handle, pixels, fields)
                except Exception as failure:  # the process's edge: any failure stops the recording, said by add
                    error = f"{type(failure).__name__}: {failure}"
                frames += not error
            write_s += time.perf_counter() - start
            del pixels  # its slot may be unmapped with the next message
            with contextlib.suppress(OSError):  # the tracker is gone: the frames still come from its socket
                channel.send(pickle.dumps((number if number >= 0 else _NO_PIXELS, frames, write_s, error)))


def _write_frame(folder: Path, handle: TextIO, pixels: np.ndarray | None, fields: tuple[Any, ...]) -> str:
    """Write one frame's PNG and then its row; returns why it could not (``""``: written)."""
    index, timestamp_s, image, error_status, error = fields
    name = "" if pixels is None else f"frame_{index:05d}.png"
    if pixels is not None:
        ok = cv2.imwrite(str(folder / name), _to_bgr(pixels), _PNG_OPTIONS)
        if not ok:
            return f"cannot write {folder / name}"
    error = "" if pixels is not None else error
    status = "" if pixels is not None else error_status
    try:
        csv.writer(handle, lineterminator="\n").writerow([index, name, f"{timestamp_s:.6f}", image, status, error])
        handle.flush()
    except OSError as failure:
        return f"cannot write {folder / FRAMES_CSV}: {failure.strerror or failure}"
    return ""


def _to_bgr(pixels: np.ndarray) -> np.ndarray:
    """A frame's pixels in OpenCV's channel order (grey as it is)."""
    if pixels.ndim == 3 and pixels.shape[2] == 3:
        return cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR)
    if pixels.ndim == 3 and pixels.shape[2] == 4:
        return cv2.cvtColor(pixels, cv2.COLOR_RGBA2BGRA)
    return pixels


@dataclass(frozen=True)
class _Row:
    frame: int
    file: str
    timestamp_s: float
    image: str
    error_status: str
    error: str


def _read_rows(folder: Path) -> list[_Row]:
    """``frames.csv``'s rows, checked."""
    path = folder / FRAMES_CSV
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            reader = csv.DictReader(handle)
            missing = [c for c in ("frame", "file", "timestamp_s") if c not in (reader.fieldnames or ())]
            if missing:
                raise InputError(f"{path}: no column {', '.join(missing)}: not a recording's {FRAMES_CSV}")
            lines = list(reader)
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"{path}: cannot read the recording: {error}") from None
    rows = []
    for number, line in enumerate(lines, start=2):
        frame, stamp = parse_int(line["frame"] or ""), parse_float(line["timestamp_s"] or "")
        if frame is None or stamp is None or not math.isfinite(stamp):
            raise InputError(f"{path}, line {number}: frame must be an integer and timestamp_s a number of seconds")
        extra = (line.get(key) or "" for key in ("image", "error_status", "error"))
        rows.append(_Row(frame, line["file"] or "", stamp, *extra))
    if not rows:
        raise InputError(f"{path}: the recording has no frames")
    return rows


def recording_fps(folder: str | Path) -> float | None:
    """The recording's frame rate, from its timestamps: one over the median interval (4 significant digits);
    None with fewer than two frames or no time between them."""
    return _rows_fps(_read_rows(Path(folder)))


def _rows_fps(rows: list[_Row]) -> float | None:
    """:func:`recording_fps` of ``frames.csv``'s rows."""
    stamps = np.array([row.timestamp_s for row in rows])
    steps = np.diff(stamps)
    steps = steps[steps > 0]
    if not len(steps):
        return None
    return float(f"{1.0 / float(np.median(steps)):.4g}")


def read_recording(
    folder: str | Path,
    *,
    speed: float = 1.0,
    expected_size: tuple[int, int] | None = None,
    stop: Callable[[], bool] = lambda: False,
    fps: Callable[[float], object] | None = None,
) -> Generator[Frame, None, None]:
    """A recording's frames, each handed over when its recorded time comes, stamped with its recorded capture time.

    Parameters
    ----------
    folder : str or Path
        A recording (see the module's docstring).
    speed : float
        1: at the recorded pace (the time between two frames as between their capture); 2: twice as fast;
        ``math.inf``: each frame as soon as it is decoded. A late frame (the caller was slow) is handed over at once,
        and the next ones keep to the recorded schedule.
    expected_size : (int, int), optional
        Width and height a frame must have (its frame then has ``error_status`` ``wrong_size``).
    stop : callable
        While it returns true the frames come at once (a stop asked for during a long pause in the recording).
    fps : callable, optional
        Called at once with the recording's frame rate (:func:`recording_fps`), if it has one.

    Raises
    ------
    InputError
        If ``frames.csv`` cannot be read, or ``speed`` is not > 0.
    """
    if not speed > 0:
        raise InputError(f"--replay-speed must be fast or a number > 0, got {speed}")
    folder = Path(folder)
    rows = _read_rows(folder)
    rate = _rows_fps(rows)
    if fps is not None and rate is not None:
        fps(rate)
    return _replay(folder, rows, speed, expected_size, stop)


def _replay(
    folder: Path, rows: list[_Row], speed: float, expected_size: tuple[int, int] | None, stop: Callable[[], bool]
) -> Generator[Frame, None, None]:
    started: float | None = None  # perf_counter seconds when the first frame was handed over
    for row in rows:
        begin = time.perf_counter()
        pixels, error, status = None, row.error or "not recorded", row.error_status or "unreadable"
        if row.file:
            try:
                pixels, error, status = read_image(folder / row.file, expected_size=expected_size), "", "unreadable"
            except ImageReadError as failure:
                error, status = str(failure), failure.status
        decoded = time.perf_counter()
        if started is None:
            started = decoded
        elif math.isfinite(speed):
            due = started + (row.timestamp_s - rows[0].timestamp_s) / speed
            while (left := due - time.perf_counter()) > 0 and not stop():
                time.sleep(min(left, _WAIT_SLICE_S))
        ready = time.perf_counter()
        yield Frame(row.frame, row.image, pixels, 1000 * (decoded - begin), ready, error, row.timestamp_s, status)
