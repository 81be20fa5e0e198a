"""A tracking session: ``track``'s application, from a frame source to ``poses.csv`` and what the run did.

:class:`TrackSession` owns the source, the stop conditions (SIGINT and SIGTERM, a
frame or time limit, frames of the wrong size), the OpenIGTLink server and the
overlay writer, and the recording of the frames; :meth:`TrackSession.run` tracks
every frame (a recording's at its recorded pace, or faster), writes each row as
it is done and returns a :class:`TrackResult` with the counts, the latencies and
why it stopped. What happens during the run (warnings, the server's address) goes
to ``report`` as it happens; the summary is the caller's to print.
"""

from __future__ import annotations

import contextlib
import ipaddress
import math
import signal
import socket
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Generator, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np

from spotnav.app.igtl import DEFAULT_DEVICE, DEFAULT_HOST, DEFAULT_STALE_S, PoseServer
from spotnav.app.overlay import draw_overlay, fitted_spots
from spotnav.app.progress import progress
from spotnav.app.status_style import status_counts
from spotnav.app.track import TrackedFrame, Tracker, frozen_heap, prepare_kernels
from spotnav.errors import SpotnavError
from spotnav.files.capture import Frame
from spotnav.files.numbers import parse_float
from spotnav.files.poses import TRACK_COLUMNS, PosesWriter, track_row
from spotnav.files.recording import RecordingWriter
from spotnav.files.sequences import CameraSettings, SequenceWriter, is_live, iter_frames
from spotnav.files.setup_files import setup_to_toml
from spotnav.pose.estimate import PoseEstimate
from spotnav.setup.config import Setup

__all__ = [
    "WRONG_SIZE_STOP",
    "IgtlSettings",
    "StopSignals",
    "TrackLimits",
    "TrackResult",
    "TrackSession",
    "camera_settings",
    "compiling_note",
    "ready",
    "replay_speed",
    "to_stderr",
]

SLOW_START_S = 2.0  # a start slower than this is compiling: say so
DEFAULT_OVERLAY_FPS = 30.0  # the overlay's frame rate when neither the source nor --fps gives one
WRONG_SIZE_STOP = 25  # consecutive frames of the wrong size that stop tracking

_Handler = Callable[[int, FrameType | None], Any] | int | signal.Handlers | None  # what signal.signal returns


def to_stderr(line: str) -> None:
    """Tell the user ``line`` on stderr (every application's default ``report``)."""
    print(line, file=sys.stderr)


@contextlib.contextmanager
def compiling_note() -> Iterator[None]:
    """Say what a slow start is doing: the first command compiled every kernel for the usual frames (8-bit colour,
    :mod:`spotnav.app.kernels`); another kind of frame (16-bit, grey) has its own compiled once, on first use."""
    note = "spotnav: preparing the numerical kernels for this kind of frame, once ..."
    timer = threading.Timer(SLOW_START_S, partial(print, note, file=sys.stderr, flush=True))
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


def ready(setup: Setup) -> None:
    """Compile (or load) the kernels before the first frame, saying so when that takes long."""
    with compiling_note():
        prepare_kernels(setup)


class StopSignals:
    """SIGINT and SIGTERM ask a loop to stop after the frame in hand, and any wait for the next frame to end: the run
    keeps every row it finished and says what it did, and the command exits 130 (issue 61: one exit for an
    interrupt, at any moment).

    A second signal of the same kind while the first is pending ends the run at once, as
    Python's default would.
    """

    def __init__(self) -> None:
        self.received: str | None = None
        self._previous: dict[int, _Handler] = {}

    def _handle(self, number: int, _frame: object) -> None:
        if self.received == signal.Signals(number).name:
            raise KeyboardInterrupt
        self.received = signal.Signals(number).name

    def __enter__(self) -> StopSignals:
        for number in (signal.SIGINT, signal.SIGTERM):
            self._previous[number] = signal.signal(number, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for number, handler in self._previous.items():
            signal.signal(number, handler)


@dataclass(frozen=True)
class TrackLimits:
    """When a run stops before its source ends: after ``max_frames`` frames, after ``duration_s`` seconds.

    Raises
    ------
    SpotnavError
        For a limit below 1 frame or not a finite number of seconds > 0 (named as ``track``'s options).
    """

    max_frames: int | None = None
    duration_s: float | None = None

    def __post_init__(self) -> None:
        if self.max_frames is not None and self.max_frames < 1:
            raise SpotnavError(f"--max-frames must be at least 1, got {self.max_frames}")
        if self.duration_s is not None and not (np.isfinite(self.duration_s) and self.duration_s > 0):
            raise SpotnavError(f"--duration must be a finite number of seconds > 0, got {self.duration_s}")


def camera_settings(size_px: Sequence[int] | None, fps: float | None, exposure: float | None) -> CameraSettings:
    """The live camera's settings asked for, checked (named as ``track``'s options).

    Raises
    ------
    SpotnavError
        For a size below 1 px, a frame rate that is not a finite number > 0, or an exposure that is not finite.
    """
    if size_px is not None and min(size_px) < 1:
        raise SpotnavError(f"--camera-size must be positive, got {' '.join(map(str, size_px))}")
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise SpotnavError(f"--fps must be a finite number > 0, got {fps}")
    if exposure is not None and not np.isfinite(exposure):
        raise SpotnavError(f"--exposure must be a finite number, got {exposure}")
    return CameraSettings((size_px[0], size_px[1]) if size_px is not None else None, fps, exposure)


def replay_speed(text: str) -> float:
    """``--replay-speed``'s value: ``fast`` (``math.inf``: each frame as soon as it is decoded) or a factor > 0 of
    the recorded pace (1: as recorded).

    Raises
    ------
    SpotnavError
        For anything else.
    """
    if text.strip().lower() == "fast":
        return math.inf
    speed = parse_float(text)
    if speed is None or not (math.isfinite(speed) and speed > 0):
        raise SpotnavError(f"--replay-speed must be fast or a number > 0 (1: the recorded pace), got {text!r}")
    return speed


@dataclass(frozen=True)
class IgtlSettings:
    """The OpenIGTLink server to serve the poses on: its port, address, device, how long to wait for a client,
    and after how long without a frame the pose is stale (s)."""

    port: int
    host: str = DEFAULT_HOST
    device: str = DEFAULT_DEVICE
    wait_s: float = 0.0
    stale_s: float = DEFAULT_STALE_S


@dataclass
class TrackResult:
    """What a tracking run did.

    Attributes
    ----------
    out : Path
        The ``poses.csv`` written.
    rows : int
        Frames written.
    statuses : Counter
        Frames per status.
    latencies : list of float
        Each frame's latency, ms, from the frame's arrival to its row.
    wrong_size : int
        Frames of the wrong size in a row at the end.
    stop : str
        Why it stopped before the source ended (``""``: the source ended).
    verdict : str
        The sequence's test: what of the setup the frames contradict (``""``: nothing).
    signal : str
        The signal that stopped it (``"SIGINT"``, ``"SIGTERM"``; ``""``: none).
    """

    out: Path
    rows: int = 0
    statuses: Counter[str] = field(default_factory=Counter)
    latencies: list[float] = field(default_factory=list)
    wrong_size: int = 0
    stop: str = ""
    verdict: str = ""
    signal: str = ""

    def summary(self) -> str:
        """``"N frames, 3 ok, 1 lost; latency ..."``: what the command line says of the run."""
        counts = status_counts(self.statuses, "no frames")
        timing = (
            f"; latency median {np.median(self.latencies):.2f} ms, 99th percentile "
            f"{np.percentile(self.latencies, 99):.2f} ms, max {np.max(self.latencies):.2f} ms"
            if self.latencies
            else ""
        )
        ended = f" ({self.stop})" if self.stop else ""
        return f"{self.rows} frames, {counts}{timing}{ended}"

    @property
    def wrong_size_stop(self) -> bool:
        """Whether the run stopped on :data:`WRONG_SIZE_STOP` frames of the wrong size in a row."""
        return self.wrong_size >= WRONG_SIZE_STOP

    @property
    def exit_code(self) -> int:
        """130 when a signal stopped the run (whatever else it met), 2 when frames of the wrong size did, else 0."""
        return 130 if self.signal else 2 if self.wrong_size_stop else 0


class TrackSession:
    """Track a source's frames into ``poses.csv``, serving and drawing each pose if asked, until a stop.

    Parameters
    ----------
    setup : Setup
    source : str
        Recording, video file, folder or glob of images, camera index, URL or GStreamer pipeline
        (:func:`spotnav.files.sequences.iter_frames`).
    out : str or Path
        The ``poses.csv`` to write.
    through_insertion : bool
        The axis through the insertion point (``precise``) or free (``precise-free``).
    limits : TrackLimits, optional
        Default: none, the run goes to the source's end.
    camera : CameraSettings, optional
        What to ask a live camera for (default: nothing). With an ``overlay`` and a source that is not live, its
        ``fps`` is the overlay's frame rate if the source has none (images).
    igtl : IgtlSettings, optional
        Serve each pose on OpenIGTLink.
    overlay : str or Path, optional
        Also write every frame with its fit drawn on it: a video or a folder, at the source's frame rate (a
        video's, a camera's, a recording's from its timestamps); for a source without one, at ``camera.fps``, or
        :data:`DEFAULT_OVERLAY_FPS` with a note.
    record : str or Path, optional
        Also keep every frame, losslessly, with its capture time, in this new folder
        (:class:`spotnav.files.recording.RecordingWriter`), written by a process of its own.
    replay_speed : float
        A recording's pace (:func:`replay_speed`): 1 as recorded (the default), 2 twice as fast, ``math.inf`` as
        fast as it decodes. Other sources ignore it.
    report : callable
        Takes each line to tell the user during the run (default: stderr).
    """

    def __init__(
        self,
        setup: Setup,
        source: str,
        out: str | Path,
        *,
        through_insertion: bool = True,
        limits: TrackLimits | None = None,
        camera: CameraSettings | None = None,
        igtl: IgtlSettings | None = None,
        overlay: str | Path | None = None,
        record: str | Path | None = None,
        replay_speed: float = 1.0,
        report: Callable[[str], None] = to_stderr,
    ) -> None:
        self.setup, self.source, self.out = setup, source, Path(out)
        self.through_insertion = through_insertion
        self.limits = limits if limits is not None else TrackLimits()
        self.camera = camera if camera is not None else CameraSettings()
        self.igtl, self.overlay, self.record, self.report = igtl, overlay, record, report
        self.replay_speed = replay_speed

    def run(self) -> TrackResult:
        """Track until the source ends or a stop is due; the rows are written as they are done.

        Raises
        ------
        SpotnavError
            For a source, an output or a server that cannot be used.
        """
        # Before the stops are caught: an interrupt while the tracker starts (seconds on a busy machine) ends the
        # command at once, with the header alone (spotnav.app.start), as one before the run began.
        with compiling_note():
            tracker = Tracker(self.setup, through_insertion=self.through_insertion)
        with StopSignals() as signals:
            rates: list[float] = []  # the source's frame rate, if it has one
            source = self._frames(tracker, signals, rates.append)
            with contextlib.closing(source) as frames:
                server = None
                try:
                    server = self._server(signals)
                    # The recording's process starts before the first frame, and keeps off the tracker's core once a
                    # video's decoder keeps the tracker to it (from the first frame on).
                    with (
                        self._recording() as recording,  # first: a folder that holds one is refused before
                        PosesWriter(self.out, TRACK_COLUMNS) as out,  # poses.csv is emptied
                        self._overlay_writer(rates[0] if rates else None) as overlay,
                        frozen_heap(),
                    ):
                        result = self._track(tracker, frames, server, signals, out, (overlay, recording))
                finally:
                    if server is not None:
                        server.close()
                        self._report_clients(server)
        result.rows = out.rows
        result.signal = signals.received or ""
        if result.signal:
            result.stop = f"stopped by {result.signal}"
        return result

    def _frames(
        self, tracker: Tracker, signals: StopSignals, fps: Callable[[float], object]
    ) -> Generator[Frame, None, None]:
        """The source's frames, opened; they end early on a stop (a video's while a frame is awaited)."""
        size = (self.setup.camera.width_px, self.setup.camera.height_px)
        # --fps asks a live source for its rate; with an overlay, it is the overlay's for a source without one.
        overlay_fps = self.overlay is not None and not is_live(self.source)
        # The tracker keeps no image: a frame's buffer is reused two frames later; a video is decoded in a
        # second process, and the tracker rehearses the last frame while it waits.
        return iter_frames(
            self.source,
            ring=2,
            camera=replace(self.camera, fps=None) if overlay_fps else self.camera,
            report=self.report,
            expected_size=size,
            while_waiting=tracker.rehearse,
            replay_speed=self.replay_speed,
            fps=fps,
            stop=lambda: bool(signals.received),
        )

    def _report_clients(self, server: PoseServer) -> None:
        """Say how many clients the server served, dropped and refused."""
        extra = [f"{server.clients_dropped} dropped for not reading"] if server.clients_dropped else []
        extra += [f"{server.clients_garbage} dropped for sending garbage"] if server.clients_garbage else []
        extra += [f"{server.clients_refused} refused (too many)"] if server.clients_refused else []
        self.report(f"OpenIGTLink: {', '.join([f'{server.clients_served} clients served', *extra])}")

    def _overlay_writer(self, source_fps: float | None) -> contextlib.AbstractContextManager[SequenceWriter | None]:
        """The overlay's video (or folder of PNGs) at the source's frame rate, or nothing."""
        if self.overlay is None:
            return contextlib.nullcontext()
        fps = source_fps or self.camera.fps
        if fps is None:
            fps = DEFAULT_OVERLAY_FPS
            self.report(
                f"spotnav: note: {self.source} has no frame rate: the overlay is written at {fps:g} fps (--fps F)"
            )
        return SequenceWriter(self.overlay, fps)

    @contextlib.contextmanager
    def _recording(self) -> Iterator[RecordingWriter | None]:
        """The recording of every frame asked for, or nothing; says what it cost once every frame is on disk."""
        if self.record is None:
            yield None
            return
        setup = setup_to_toml(self.setup, f"The setup spotnav track used on {self.source}")
        with RecordingWriter(self.record, setup, report=self.report) as recording:
            yield recording
        frames = max(recording.frames, 1)
        waited = f" and {recording.wait_s:.1f} s waiting for the disk" if recording.wait_s else ""
        self.report(
            f"recorded {recording.frames} frames in {recording.folder}: {1000 * recording.copy_s / frames:.2f} ms a "
            f"frame copying in the tracker's thread{waited}, {1000 * recording.write_s / frames:.1f} ms a frame "
            "writing in a process of its own"
        )

    def _server(self, signals: StopSignals) -> PoseServer | None:
        """The OpenIGTLink server asked for (None without it), with what it tells the user."""
        if self.igtl is None:
            return None
        igtl = self.igtl
        server = PoseServer(igtl.port, host=igtl.host, device=igtl.device, stale_s=igtl.stale_s, report=self.report)
        where = f"{server.host}:{server.port}"
        self.report(f"OpenIGTLink: {server.device} (TRANSFORM) and {server.device}Status (STRING) on {where}")
        if not ipaddress.ip_address(socket.gethostbyname(server.host)).is_loopback:
            self.report(
                f"spotnav: warning: OpenIGTLink has no authentication: anyone who reaches {server.host}:{server.port} "
                "receives the poses"
            )
        if self.igtl.wait_s > 0:
            self.report(f"OpenIGTLink: waiting up to {self.igtl.wait_s:g} s for a client ...")
            connected = server.wait_for_client(self.igtl.wait_s, stop=lambda: bool(signals.received))
            self.report(f"OpenIGTLink: {'a client is connected' if connected else 'no client yet'}")
        return server

    def _track(
        self,
        tracker: Tracker,
        frames: Iterable[Frame],
        server: PoseServer | None,
        signals: StopSignals,
        out: PosesWriter,
        outputs: tuple[SequenceWriter | None, RecordingWriter | None],
    ) -> TrackResult:
        """Track every frame, writing each row (and the overlay, the recording) as it is done, until a stop."""
        overlay, recording = outputs
        result = TrackResult(self.out)
        started = time.monotonic()
        bar = progress(frames, desc="track", unit="frame")
        for frame in bar:
            if signals.received:  # it came while this frame was awaited: the run ends without it
                break
            if frame.pixels is None:
                tracker.lose()
                tracked = TrackedFrame(PoseEstimate(frame.error_status, detail=frame.error), "lost")
            else:
                tracked = tracker.update(frame.pixels)
            latency = 1000 * (time.perf_counter() - frame.ready_s)
            if server is not None:
                server.send(tracked.estimate, frame.index, frame.timestamp_s, tracked.mode)
            out.write(track_row(frame, tracked.estimate, tracked.mode, latency))
            if recording is not None:
                recording.add(frame)
            if overlay is not None and frame.pixels is not None:
                label = f"frame {frame.index}, {tracked.mode}"
                spots = fitted_spots(tracked.edges_px)
                canvas = draw_overlay(frame.pixels, tracker.setup, tracked.estimate, spots=spots, label=label)
                overlay.write(frame.index, canvas)
            result.statuses[tracked.estimate.status] += 1
            if tracker.sequence.verdict and not result.verdict:  # said once; every frame's row and status carry it
                result.verdict = tracker.sequence.verdict
                self.report(f"spotnav: warning: frame {frame.index}: {result.verdict}")
            result.latencies.append(latency)
            bar.set_postfix_str(f"{1000 / max(np.median(result.latencies[-50:]), 1e-3):.0f} Hz, {tracked.mode}")
            streamed = not frame.image  # a video's or a camera's frame, not a file of a batch
            result.wrong_size = result.wrong_size + 1 if tracked.estimate.status == "wrong_size" and streamed else 0
            if result.wrong_size == 1:
                self.report(f"spotnav: warning: frame {frame.index}: {tracked.estimate.detail}")
            result.stop = self._stop(signals, out.rows, time.monotonic() - started, result.wrong_size)
            if result.stop:
                break
        bar.close()
        return result

    def _stop(self, signals: StopSignals, frames: int, elapsed_s: float, wrong_size: int) -> str:
        """Why tracking stops after this frame, or ``""`` to go on."""
        limits = self.limits
        if signals.received:
            return f"stopped by {signals.received}"
        if limits.max_frames is not None and frames >= limits.max_frames:
            return f"--max-frames {limits.max_frames}"
        if limits.duration_s is not None and elapsed_s >= limits.duration_s:
            return f"--duration {limits.duration_s:g} s"
        if wrong_size >= WRONG_SIZE_STOP:
            return "frames of the wrong size"
        return ""
