"""The video decoder process: a video file's frames decoded on other cores, into a ring of shared memory.

:func:`read_capture_in_process` starts :func:`decode_frames_main` in a new interpreter, keeps the caller's thread to
the core it runs on and the decoder to the others, and hands over the frames it decodes into a ring of buffers in
anonymous shared memory, one frame ahead; without a second core or the memory it reads in this thread instead
(:func:`spotnav.files.capture.read_capture`).
"""

from __future__ import annotations

import contextlib
import math
import mmap
import os
import select
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Generator
from pathlib import Path

import cv2
import numpy as np

from spotnav.files.capture import Frame, grabbed, open_capture, read_capture
from spotnav.files.images import ImageReadError
from spotnav.files.numbers import parse_int
from spotnav.files.processes import shared_memory, start_python

__all__ = ["decode_frames_main", "read_capture_in_process"]


_DECODER_JOIN_S = 5.0  # how long a decoder that sent the video's end may take to exit
_STOP_POLL_MS = 50  # awaiting the first frame (nothing to rehearse), the stop is looked at this often
# A decoder process's record of a frame: its index (or _END, or _FAILED), the length of the note that follows (why
# a frame has no pixels, or the failure), decoding ms, Unix seconds when grabbed, perf_counter seconds when decoded.
_RECORD = struct.Struct("<qqddd")
_END, _FAILED = -1, -2


def _split_cores() -> tuple[set[int], set[int]]:
    """One core for the caller's thread, the one it runs on (the scheduler's choice keeps two trackers on one
    machine apart), and the others for a decoder, of those this thread may run on; two empty sets with fewer than
    two (or where threads cannot be kept to cores)."""
    cores = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else set()
    if len(cores) < 2:
        return set(), set()
    own = {_current_core(cores)}
    return own, cores - own


def _current_core(cores: set[int]) -> int:
    """The core this thread last ran on (Linux's ``/proc``), if it is one of ``cores``; else the first of them."""
    try:
        stat = Path(f"/proc/self/task/{threading.get_native_id()}/stat").read_text()
    except (OSError, UnicodeDecodeError):
        return min(cores)
    _, name_end, after_name = stat.rpartition(")")
    fields = after_name.split()  # the fields after the name, from 3: field 39, "processor", is the 37th
    core = parse_int(fields[36]) if name_end and len(fields) > 36 else None
    return core if core is not None and core in cores else min(cores)


def read_capture_in_process(
    source: str,
    capture: cv2.VideoCapture,
    ring: int,
    while_waiting: Callable[[np.ndarray], object],
    stop: Callable[[], bool] = lambda: False,
) -> Generator[Frame, None, None]:
    """:func:`~spotnav.files.sequences.iter_frames`'s video frames from a decoder process, through a ring of
    ``ring + 1`` buffers in shared memory: a frame's buffer is written again once the frame ``ring`` later is handed
    over; the frames end early once ``stop`` returns true while the next one is awaited. In this thread, as
    :func:`~spotnav.files.capture.read_capture`, without a second core to decode on or shared memory to decode
    into."""
    own, others = _split_cores()
    shape = (ring + 1, int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)), int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), 3)
    buffers = shared_memory(math.prod(shape), "spotnav-frames") if own and min(shape) > 0 else None
    if buffers is None:
        return read_capture(capture, ring)
    capture.release()
    return _frames_from_process(source, buffers, shape, (own, others), (while_waiting, stop))


def _frames_from_process(
    source: str,
    buffers: int,
    shape: tuple[int, int, int, int],
    cores: tuple[set[int], set[int]],
    waiting: tuple[Callable[[np.ndarray], object], Callable[[], bool]],
) -> Generator[Frame, None, None]:
    """Start :func:`decode_frames_main` in a new interpreter (not a fork: OpenCV's threads do not survive one) and
    hand over the frames it decodes into ``buffers`` (a file descriptor), this thread on the first of ``cores``
    (own, the decoder's) meanwhile. While a frame is awaited, ``waiting``'s first is called with the last one's
    pixels, again and again; its second, asked before each frame and while one is awaited, ends the frames when it
    returns true (a Ctrl-C): the decoder is then killed, not waited for (it may still be starting, or decoding a
    frame no one will read).

    The decoder decodes a frame once the one before was handed over (a byte on its standard input each) and sends
    a :data:`_RECORD` for each, then :data:`_END` (or :data:`_FAILED`), each followed by its note if any. It runs in
    its own session: a signal to this process group is this process's to act on.
    """
    own, others = cores
    while_waiting, stop = waiting
    # Mapped in full now (Linux's MAP_POPULATE), not page by page as the first frames are read: that cost the first
    # frame, an acquisition, 190 page faults and 2-4 ms.
    populate = mmap.MAP_SHARED | getattr(mmap, "MAP_POPULATE", 0)
    ring = np.frombuffer(mmap.mmap(buffers, math.prod(shape), flags=populate), dtype=np.uint8).reshape(shape)
    records, records_out = os.pipe()
    arguments = [source, str(buffers), ",".join(map(str, shape)), str(records_out), ",".join(map(str, others))]
    decoder = start_python(
        "spotnav.files.decoder:decode_frames_main",
        arguments,
        stdin=subprocess.PIPE,
        pass_fds=(buffers, records_out),
        start_new_session=True,
    )
    to_decoder = decoder.stdin
    if to_decoder is None:  # impossible: stdin=subprocess.PIPE gives the process a pipe
        raise ImageReadError(f"{source}: the decoder process has no standard input")
    os.close(records_out)
    os.close(buffers)
    arrived = select.poll()
    arrived.register(records, select.POLLIN)
    affinity = os.sched_getaffinity(0)
    ended = False  # the decoder said the video's end (or its failure): it ends by itself
    try:
        os.sched_setaffinity(0, own)
        last: np.ndarray | None = None
        while True:
            asked = time.perf_counter()
            while not stop():
                if arrived.poll(0 if last is not None else _STOP_POLL_MS):
                    break
                if last is not None:
                    while_waiting(last)
            else:  # a stop while the frame was awaited (or before): no more frames
                return
            record = _read_exactly(records, _RECORD.size)
            if len(record) < _RECORD.size:
                code = decoder.wait(_DECODER_JOIN_S)
                raise ImageReadError(f"{source}: the decoder process ended before the video did (exit code {code})")
            index, note_length, decode_ms, stamp, decoded = _RECORD.unpack(record)
            note = _read_exactly(records, note_length).decode(errors="replace")
            ended = index in (_END, _FAILED)
            if index == _END:
                return
            if index == _FAILED:
                raise ImageReadError(note)
            pixels = None if note else ring[index % len(ring)]
            with contextlib.suppress(BrokenPipeError):  # a decoder that died: the next read says so
                os.write(to_decoder.fileno(), b"\0")  # the decoder may go on with the next frame
            last = last if pixels is None else pixels
            ready = max(decoded, asked)
            yield Frame(index, "", pixels, decode_ms, ready, note, stamp, "wrong_size" if note else "unreadable")
    finally:
        try:
            os.sched_setaffinity(0, affinity)
        finally:
            os.close(records)
            to_decoder.close()
            try:
                decoder.wait(_DECODER_JOIN_S if ended else 0)
            except subprocess.TimeoutExpired:  # stopped early (or stuck): nothing of its work is left to keep
                decoder.kill()
                decoder.wait()


def _read_exactly(descriptor: int, size: int) -> bytes:
    """``size`` bytes from a pipe, or fewer if it ends first."""
    data = b""
    while len(data) < size:
        more = os.read(descriptor, size - len(data))
        if not more:
            break
        data += more
    return data


def _send_record(
    descriptor: int, index: int, note: str = "", times: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> None:
    """One :data:`_RECORD` and its note."""
    encoded = note.encode()
    os.write(descriptor, _RECORD.pack(index, len(encoded), *times) + encoded)


def decode_frames_main() -> None:
    """A decoder process's work (started by :func:`_frames_from_process`; its arguments: the source, the buffers'
    file descriptor, their shape, the records' file descriptor and the cores to run on, comma-separated).

    Frame ``k`` is decoded into buffer ``k % len(buffers)``, the first at once and each next one when a byte on
    standard input says that the one before was handed over; a frame of another size is not (its record's note
    says why). The process ends at the video's end or when its standard input does (the parent stopped, or is
    gone); a failure is sent as :data:`_FAILED` with its message.
    """
    source, buffers, shape_text, descriptor, cores = sys.argv[1:]
    records = int(descriptor)
    try:
        if cores:
            os.sched_setaffinity(0, {int(core) for core in cores.split(",")})
        shape = tuple(int(n) for n in shape_text.split(","))
        ring = np.frombuffer(mmap.mmap(int(buffers), math.prod(shape)), dtype=np.uint8).reshape(shape)
        _decode_into(open_capture(source, {}), ring, records)
    except BrokenPipeError:  # the parent stopped reading
        return
    except Exception as error:  # any failure is the parent's to report, in one line
        with contextlib.suppress(BrokenPipeError):
            _send_record(records, _FAILED, f"{source}: the decoder process failed: {error}")


def _decode_into(capture: cv2.VideoCapture, ring: np.ndarray, records: int) -> None:
    """:func:`decode_frames_main`'s loop: ``capture``'s frames into the buffers ``ring`` (B, H, W, 3), each next
    one once a byte on standard input says so."""
    frames = grabbed(capture, reuse=True)
    with contextlib.closing(frames):
        for index, (decoded, start, stamp) in enumerate(frames):
            times = (1000 * (time.perf_counter() - start), stamp)
            note = ""
            if decoded.shape != ring.shape[1:] or decoded.dtype != np.uint8:
                size, first = f"{decoded.shape[1]}x{decoded.shape[0]}", f"{ring.shape[2]}x{ring.shape[1]}"
                note = f"frame {index} is {size} px {decoded.dtype}, the video's first {first} px uint8"
            else:
                cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB, dst=ring[index % len(ring)])
            _send_record(records, index, note, (*times, time.perf_counter()))
            if not os.read(0, 1):  # the frame was handed over: decode the next one (or the parent stopped)
                return
        _send_record(records, _END)
