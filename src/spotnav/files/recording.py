"""A tracking session's recording: every frame kept losslessly with its capture time, and replayed at its pace.

A recording is a folder:

- ``frame_00000.png``, ... : each frame as the source gave it (grey or RGB, 8 or 16 bits), lossless PNG;
- ``frames.csv`` (:data:`RECORDING_COLUMNS`): ``frame`` (the source's index), ``file`` (the PNG, empty for a frame
  the source could not give), ``timestamp_s`` (the capture time, Unix seconds), ``image`` (the source's image file,
  empty for a video or camera frame), ``error_status`` and ``error`` (why a frame has no PNG);
- ``setup.toml``: the setup the session tracked with.

:class:`RecordingWriter` copies each frame in the caller's thread (its only cost there) and writes it in a thread of
its own, in order, each row of ``frames.csv`` on disk once its PNG is; :func:`read_recording` replays a recording
as a sequence of :class:`~spotnav.files.capture.Frame` at its original pace (or faster), each stamped with its
recorded capture time.
"""

from __future__ import annotations

import csv
import math
import queue
import threading
import time
from collections.abc import Callable, Generator
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from spotnav.errors import InputError
from spotnav.files.capture import Frame
from spotnav.files.images import ImageReadError, read_image
from spotnav.files.numbers import parse_float, parse_int

__all__ = [
    "FRAMES_CSV",
    "MAX_PENDING_BYTES",
    "RECORDING_COLUMNS",
    "SETUP_TOML",
    "RecordingWriter",
    "is_recording",
    "read_recording",
    "recording_fps",
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
_SAY_LEFT = 20  # closing with this many frames still to write says so
_WAIT_SLICE_S = 0.05  # a replay waiting for a frame's time looks at its stop this often


def is_recording(source: str) -> bool:
    """Whether ``source`` is a recording's folder (it holds :data:`FRAMES_CSV`)."""
    return (Path(source) / FRAMES_CSV).is_file()


@dataclass(frozen=True)
class _Pending:
    frame: Frame
    pixels: np.ndarray | None


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
        If the folder holds a recording already, or cannot be written.

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
        Time the writing thread took to encode and write the frames, s, in total.
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
            self._handle = (self.folder / FRAMES_CSV).open("w", newline="", encoding="utf-8")
        except OSError as error:
            raise InputError(f"{self.folder}: cannot write the recording: {error.strerror or error}") from None
        self._csv = csv.writer(self._handle, lineterminator="\n")
        self._csv.writerow(RECORDING_COLUMNS)
        self.max_pending_bytes, self.report = max_pending_bytes, report
        self.frames, self.copy_s, self.wait_s, self.write_s = 0, 0.0, 0.0, 0.0
        self.error = ""  # why the writing thread stopped writing
        self._said_behind = False
        self._pending_bytes = 0
        self._room = threading.Condition()
        self._spare: list[np.ndarray] = []  # buffers of frames written, to copy the next ones into
        self._queue: queue.SimpleQueue[_Pending | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._write_all, name="spotnav-record", daemon=True)
        self._thread.start()

    def add(self, frame: Frame) -> None:
        """Copy ``frame`` (its buffer may be reused) and queue it for the writing thread.

        Raises
        ------
        InputError
            If a frame could not be written (the disk is full, the folder gone).
        """
        start = time.perf_counter()
        if self.error:
            raise InputError(f"{self.folder}: recording stopped: {self.error}")
        size = 0 if frame.pixels is None else frame.pixels.nbytes
        waited = 0.0
        with self._room:
            if self._pending_bytes + size > max(self.max_pending_bytes, size):
                if not self._said_behind and self.report is not None:
                    self._said_behind = True
                    self.report(f"spotnav: warning: {self.folder}: the disk is behind: tracking waits for it")
                waiting = time.perf_counter()
                self._room.wait_for(lambda: self._pending_bytes + size <= max(self.max_pending_bytes, size))
                waited = time.perf_counter() - waiting
            self._pending_bytes += size
            spare = None if frame.pixels is None else self._take_spare(frame.pixels)
        pixels = None
        if frame.pixels is not None:
            pixels = frame.pixels.copy() if spare is None else spare
            if spare is not None:
                np.copyto(spare, frame.pixels)
        self._queue.put(_Pending(replace(frame, pixels=None), pixels))  # the copy alone stays in memory
        self.wait_s += waited
        self.copy_s += time.perf_counter() - start - waited

    def _take_spare(self, pixels: np.ndarray) -> np.ndarray | None:
        """A written frame's buffer of ``pixels``'s shape and type, taken from the spares (with the lock held)."""
        for index, spare in enumerate(self._spare):
            if spare.shape == pixels.shape and spare.dtype == pixels.dtype:
                return self._spare.pop(index)
        return None

    def close(self) -> None:
        """Wait until every queued frame is on disk (saying so when many wait), then close ``frames.csv``.

        Raises
        ------
        InputError
            If a frame could not be written: the recording lacks it and those after it.
        """
        try:
            if self._thread.is_alive():
                left = self._queue.qsize()
                if left >= _SAY_LEFT and self.report is not None:
                    self.report(f"{self.folder}: writing the {left} frames still in memory ...")
                self._queue.put(None)
                self._thread.join()
        finally:
            self._handle.close()
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

    def _write_all(self) -> None:
        """The writing thread: each queued frame's PNG, then its row, in order, until :meth:`close`."""
        while (pending := self._queue.get()) is not None:
            start = time.perf_counter()
            try:
                if not self.error:
                    self.error = self._write(pending)
            except Exception as failure:  # the thread's edge: any failure stops the recording, said by add and close
                self.error = f"{type(failure).__name__}: {failure}"
            self.write_s += time.perf_counter() - start
            with self._room:  # the frame's memory is given back whatever happened, so that add never waits forever
                if pending.pixels is not None:
                    self._pending_bytes -= pending.pixels.nbytes
                    if len(self._spare) < _SPARE_BUFFERS:
                        self._spare.append(pending.pixels)
                self._room.notify_all()

    def _write(self, pending: _Pending) -> str:
        """Write one frame and its row; returns why it could not (``""``: written)."""
        frame, pixels = pending.frame, pending.pixels
        name = "" if pixels is None else f"frame_{frame.index:05d}.png"
        if pixels is not None:
            ok = cv2.imwrite(str(self.folder / name), _to_bgr(pixels), _PNG_OPTIONS)
            if not ok:
                return f"cannot write {self.folder / name}"
        error = "" if pixels is not None else frame.error
        status = "" if pixels is not None else frame.error_status
        try:
            self._csv.writerow([frame.index, name, f"{frame.timestamp_s:.6f}", frame.image, status, error])
            self._handle.flush()
        except OSError as failure:
            return f"cannot write {self.folder / FRAMES_CSV}: {failure.strerror or failure}"
        self.frames += 1
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
