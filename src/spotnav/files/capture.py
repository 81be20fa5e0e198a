"""OpenCV's captures: a video file, camera, URL or GStreamer pipeline opened, and its frames decoded in this thread.

:class:`Frame` is what every sequence hands over (:func:`spotnav.files.sequences.iter_frames`); :func:`read_capture`
makes them from a capture, into fresh buffers or a ring of them, as :mod:`spotnav.files.decoder` does in a second
process.
"""

from __future__ import annotations

import time
from collections.abc import Generator, Mapping
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from spotnav.files.images import ImageReadError

__all__ = ["VIDEO_SUFFIXES", "Frame", "grabbed", "open_capture", "read_capture"]


VIDEO_SUFFIXES = (".mkv", ".avi", ".mp4", ".mov")


@dataclass(frozen=True)
class Frame:
    """One decoded frame of a sequence.

    Attributes
    ----------
    index : int
        Position in the sequence, from 0.
    image : str
        The image file's path, or ``""`` for a video or camera frame.
    pixels : ndarray or None
        RGB (or grey) pixels; None when the file could not be read (see ``error``).
    decode_ms : float
        Time spent reading and decoding, ms.
    ready_s : float
        When the frame was decoded and asked for, the later of the two,
        :func:`time.perf_counter` seconds (one clock for every process on
        Linux): where its latency starts.
    error : str
        Why ``pixels`` is None.
    timestamp_s : float
        When the frame arrived, Unix seconds: when OpenCV grabbed a video's or
        a live source's frame (before decoding it; a camera's driver may have
        held it a few frames before), when a file was read.
    error_status : str
        The status of a frame without ``pixels``: ``unreadable`` or ``wrong_size``.
    """

    index: int
    image: str
    pixels: np.ndarray | None
    decode_ms: float
    ready_s: float
    error: str = ""
    timestamp_s: float = 0.0
    error_status: str = "unreadable"


def grabbed(capture: cv2.VideoCapture, reuse: bool) -> Generator[tuple[np.ndarray, float, float], None, None]:
    """``capture``'s frames as OpenCV decodes them (BGR; into one buffer with ``reuse``), each with the
    :func:`time.perf_counter` seconds when its decoding started and the Unix seconds when it was grabbed; the capture
    is released at the end."""
    decoded: np.ndarray | None = None
    try:
        while True:
            start = time.perf_counter()
            if not capture.grab():
                return
            stamp = time.time()
            ok, decoded = capture.retrieve(decoded if reuse else None)
            if not ok:
                return
            yield decoded, start, stamp
    finally:
        capture.release()


def read_capture(capture: cv2.VideoCapture, ring: int) -> Generator[Frame, None, None]:
    buffers: list[np.ndarray | None] = [None] * max(ring, 1)
    for index, (decoded, start, stamp) in enumerate(grabbed(capture, bool(ring))):
        slot = index % len(buffers)
        pixels = cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB, dst=buffers[slot])
        if ring:
            buffers[slot] = pixels
        ready = time.perf_counter()
        yield Frame(index, "", pixels, 1000 * (ready - start), ready, timestamp_s=stamp)


def open_capture(source: str, wanted: Mapping[int, float]) -> cv2.VideoCapture:
    """An opened capture of a video file, camera index, URL or GStreamer pipeline, with ``wanted`` properties."""
    # One decoding thread: threads that decode ahead would compete with the localizer for the cores.
    params = [cv2.CAP_PROP_N_THREADS, 1]
    if source.isdigit():  # a camera backend (V4L2) may refuse open parameters: none
        capture = cv2.VideoCapture(int(source), cv2.CAP_ANY)
    elif " ! " in source:
        if "GStreamer:                   YES" not in cv2.getBuildInformation():
            raise ImageReadError(f"{source}: this OpenCV has no GStreamer (cv2.getBuildInformation())")
        capture = cv2.VideoCapture(source, cv2.CAP_GSTREAMER)
    elif "://" in source:
        capture = cv2.VideoCapture(source, cv2.CAP_FFMPEG, params)
    elif Path(source).is_file() and Path(source).suffix.lower() in VIDEO_SUFFIXES:
        capture = cv2.VideoCapture(source, cv2.CAP_FFMPEG, params)
    elif Path(source).is_file():
        raise ImageReadError(f"{source}: not a video ({', '.join(VIDEO_SUFFIXES)}), folder or glob of images")
    elif Path(source).exists():
        raise ImageReadError(f"{source}: not a file, folder or glob of images")
    else:
        raise ImageReadError(f"{source}: no such file, folder, camera or URL")
    if not capture.isOpened():
        raise ImageReadError(f"{source}: cannot open the video, camera, URL or pipeline")
    for number, value in wanted.items():
        capture.set(number, value)
    return capture
