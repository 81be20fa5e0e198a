"""Sequences: the frames of a folder or glob of images, a video, a camera, a URL or a pipeline, and frames written.

:func:`iter_frames` decodes a sequence in order into frames (:class:`~spotnav.files.capture.Frame`; a video, on request,
in a decoder process: :mod:`spotnav.files.decoder`), asking a live source for :class:`CameraSettings`;
:class:`SequenceWriter` writes frames as numbered PNGs or a lossless FFV1 video.
"""

from __future__ import annotations

import glob
import math
import time
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from spotnav.errors import InputError
from spotnav.files.capture import VIDEO_SUFFIXES, Frame, open_capture, read_capture
from spotnav.files.decoder import read_capture_in_process
from spotnav.files.images import ImageReadError, display_name, read_image, write_image
from spotnav.files.recording import is_recording, read_recording

__all__ = ["IMAGE_SUFFIXES", "CameraSettings", "SequenceWriter", "is_live", "iter_frames"]


IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg")


@dataclass(frozen=True)
class CameraSettings:
    """What to ask a live camera for, through OpenCV's capture properties; None keeps the camera's own.

    Attributes
    ----------
    size_px : (int, int) or None
        Width and height, px (``CAP_PROP_FRAME_WIDTH``, ``CAP_PROP_FRAME_HEIGHT``).
    fps : float or None
        Frames per second (``CAP_PROP_FPS``).
    exposure : float or None
        ``CAP_PROP_EXPOSURE``, in the capture backend's own units.
    """

    size_px: tuple[int, int] | None = None
    fps: float | None = None
    exposure: float | None = None

    def requests(self) -> dict[int, float]:
        """OpenCV property -> value, for the settings that are given."""
        wanted: dict[int, float] = {}
        if self.size_px is not None:
            wanted[cv2.CAP_PROP_FRAME_WIDTH], wanted[cv2.CAP_PROP_FRAME_HEIGHT] = self.size_px
        if self.fps is not None:
            wanted[cv2.CAP_PROP_FPS] = self.fps
        if self.exposure is not None:
            wanted[cv2.CAP_PROP_EXPOSURE] = self.exposure
        return wanted


PROPERTY_NAMES = {
    cv2.CAP_PROP_FRAME_WIDTH: "width",
    cv2.CAP_PROP_FRAME_HEIGHT: "height",
    cv2.CAP_PROP_FPS: "fps",
    cv2.CAP_PROP_EXPOSURE: "exposure",
}


def _sequence_files(source: str) -> list[str] | None:
    """The image files a folder or glob names, sorted; None when ``source`` is neither."""
    path = Path(source)
    if path.is_dir():
        return sorted(str(p) for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if any(c in source for c in "*?["):
        return sorted(glob.glob(source))
    return None


def is_live(source: str) -> bool:
    """Whether ``source`` names a live camera or stream: a camera index, a URL or a GStreamer pipeline."""
    return source.isdigit() or "://" in source or " ! " in source


def iter_frames(
    source: str,
    *,
    ring: int = 0,
    camera: CameraSettings | None = None,
    report: Callable[[str], None] | None = None,
    expected_size: tuple[int, int] | None = None,
    while_waiting: Callable[[np.ndarray], object] | None = None,
    replay_speed: float = math.inf,
    fps: Callable[[float], object] | None = None,
    stop: Callable[[], bool] = lambda: False,
) -> Generator[Frame, None, None]:
    """Decode a sequence in order: a recording, a folder or glob of images, a video file, a camera, a URL or a pipeline.

    Parameters
    ----------
    source : str
        A recording's folder (:mod:`spotnav.files.recording`), a folder or glob of images, a video file, a camera
        index (``0``), any
        URL that OpenCV's FFmpeg opens (``rtsp://...``), or a GStreamer
        pipeline (``... ! appsink``, with an OpenCV built with GStreamer).
    ring : int
        Decode video and camera frames into a ring of this many buffers, as a
        camera driver does: a frame's pixels are then overwritten ``ring``
        frames later (copy them to keep them). Fresh buffers for every frame
        (0, the default) cost a large allocation each, whose zeroing evicts
        the caches the localizer runs from.
    camera : CameraSettings, optional
        Settings to ask a live source for.
    report : callable, optional
        Receives one line with what a live source says it delivers.
    expected_size : (int, int), optional
        Width and height an image file must have: one that is not is not
        decoded (its frame's ``error_status`` is ``wrong_size``).
    while_waiting : callable, optional
        Decode a video file in a second process instead, one frame ahead, on
        other cores than the caller's thread, which is kept to the core it
        runs on while it iterates (threads it starts meanwhile stay there
        too; two trackers on one machine keep to two cores). While the
        next frame is not decoded yet, this is called with the last frame's
        pixels, again and again (:meth:`spotnav.app.track.Tracker.rehearse`
        keeps a tracked frame's code and data in that core's caches).
        ``ring`` must then be at least 1; frames are kept for ``ring`` frames
        as above. On Linux with two cores or more; elsewhere, and without
        room for the shared buffers, the video is decoded in the caller's
        thread, as are images and live sources.
    replay_speed : float
        A recording's pace: 1 as recorded, 2 twice as fast, ``math.inf`` (the default) as fast as it decodes
        (:func:`spotnav.files.recording.read_recording`).
    fps : callable, optional
        Called once, before the first frame, with the source's frame rate (frames per second) if it has one: a
        video's or a live source's (as it reports it), a recording's (from its timestamps); not for images.
    stop : callable
        A stop asked for (Ctrl-C): while it returns true, a recording waiting for a frame's time hands it over at
        once, and a video awaited from its decoder process ends.

    Raises
    ------
    ImageReadError
        If ``source`` names nothing that can be read (an unreadable image
        inside a folder yields a :class:`Frame` with its ``error`` instead),
        or a decoder process ends without the video's end.
    InputError
        If a recording's ``frames.csv`` cannot be read, or ``camera`` settings are given for a source that is not
        live.
    """
    if ring < 0 or (while_waiting is not None and ring < 1):
        raise ValueError(f"ring must be at least {0 if while_waiting is None else 1}, got {ring}")
    wanted = camera.requests() if camera is not None else {}
    if wanted and not is_live(source):
        raise InputError(f"{source}: camera settings need a live camera, URL or pipeline, not files")
    if is_recording(source):
        return read_recording(source, speed=replay_speed, expected_size=expected_size, stop=stop, fps=fps)
    files = _sequence_files(source)
    if files is not None:
        if not files:
            raise ImageReadError(f"{source}: no images ({', '.join(IMAGE_SUFFIXES)})")
        return _read_files(files, expected_size)
    capture = open_capture(source, wanted)
    if is_live(source) and report is not None:
        delivered = ", ".join(f"{PROPERTY_NAMES[p]} {capture.get(p):g}" for p in PROPERTY_NAMES)
        report(f"{source}: the source reports {delivered}")
        for number, value in wanted.items():
            if abs(capture.get(number) - value) > 1e-6 * max(abs(value), 1.0):
                report(f"{source}: asked for {PROPERTY_NAMES[number]} {value:g}, it reports {capture.get(number):g}")
    rate = capture.get(cv2.CAP_PROP_FPS)
    if fps is not None and math.isfinite(rate) and rate > 0:
        fps(rate)
    if while_waiting is not None and not is_live(source):
        return read_capture_in_process(source, capture, ring, while_waiting, stop)
    return read_capture(capture, ring)


def _read_files(files: Sequence[str], expected_size: tuple[int, int] | None) -> Generator[Frame, None, None]:
    for index, name in enumerate(files):
        start = time.perf_counter()
        stamp = time.time()
        try:
            pixels, error, status = read_image(name, expected_size=expected_size), "", "unreadable"
        except ImageReadError as failure:
            pixels, error, status = None, str(failure), failure.status
        ready = time.perf_counter()
        yield Frame(index, display_name(name), pixels, 1000 * (ready - start), ready, error, stamp, status)


class SequenceWriter:
    """Write frames as numbered PNGs in a folder, or as a lossless FFV1 video (``.mkv``).

    Parameters
    ----------
    out : str or Path
        A folder, or a file with a suffix in :data:`VIDEO_SUFFIXES` (FFV1 in Matroska: use ``.mkv``).
    fps : float
        The video's frame rate.
    """

    def __init__(self, out: str | Path, fps: float) -> None:
        self.out = Path(out)
        self.fps = fps
        self.video = self.out.suffix.lower() in VIDEO_SUFFIXES
        if self.video and self.out.suffix.lower() != ".mkv":
            raise InputError(f"{self.out}: lossless video is written as FFV1 in Matroska: use .mkv")
        self._writer: cv2.VideoWriter | None = None
        (self.out.parent if self.video else self.out).mkdir(parents=True, exist_ok=True)

    def write(self, index: int, rgb: np.ndarray) -> str:
        """Write one frame; returns the PNG's file name (``""`` for a video)."""
        if not self.video:
            name = f"frame_{index:05d}.png"
            write_image(self.out / name, rgb)
            return name
        if self._writer is None:
            height, width = rgb.shape[:2]
            fourcc = cv2.VideoWriter.fourcc(*"FFV1")
            self._writer = cv2.VideoWriter(str(self.out), fourcc, self.fps, (width, height))
            if not self._writer.isOpened():
                raise InputError(f"{self.out}: cannot write an FFV1 video")
        self._writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        return ""

    def close(self) -> None:
        """Finish the video."""
        if self._writer is not None:
            self._writer.release()

    def __enter__(self) -> SequenceWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
