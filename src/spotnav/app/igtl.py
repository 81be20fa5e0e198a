"""Stream poses to 3D Slicer (OpenIGTLinkIF) or any OpenIGTLink client, as PLUS does.

Every frame sends two messages to every connected client:

- a TRANSFORM named ``device`` (``TipToEye`` by default, PLUS's ``FromToTo``
  convention): the homogeneous transform from the instrument's frame to the
  eye frame (:func:`spotnav.setup.geometry.instrument_to_eye`), translation in
  millimetres. Its metadata (OpenIGTLink 3, header version 2) carries
  ``TransformStatus`` = ``OK`` or ``INVALID`` as PLUS marks it; a frame without
  a pose repeats the last pose (identity before the first) as ``INVALID``.
- a STRING named ``device + "Status"``: the frame's status as JSON
  (``{"frame": 12, "status": "ok", "sigma_mm": 0.0021, "mode": "tracked"}``); a
  ``mismatch`` frame adds its ``detail``: what of the setup the frame or the
  sequence contradicts, and the command that calibrates it.

Both carry the frame's capture time as their timestamp. The server is spotnav's
own loop around pyigtl's message classes, on its own thread: it never reads
what clients send (garbage, half headers and commands are discarded), a client
that closes or fails is dropped, a client that stops reading is dropped once
over 1 MiB waits for it and none of it went out for a second, and at most 16
clients are served at once, so that no client can stall tracking or starve
another. OpenIGTLink has no authentication: the server listens on the
loopback interface unless told otherwise.
"""

from __future__ import annotations

import json
import selectors
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pyigtl

from spotnav.errors import SpotnavError
from spotnav.pose.estimate import PoseEstimate
from spotnav.setup.geometry import instrument_to_eye

__all__ = [
    "DEFAULT_DEVICE",
    "DEFAULT_HOST",
    "DEFAULT_PORT",
    "MAX_BACKLOG_BYTES",
    "MAX_CLIENTS",
    "STALL_S",
    "IgtlError",
    "PoseServer",
]

DEFAULT_PORT = 18944
DEFAULT_HOST = "127.0.0.1"
DEFAULT_DEVICE = "TipToEye"
_DEVICE_BYTES = 20  # OpenIGTLink's device name field
_STATUS_SUFFIX = "Status"
MAX_BACKLOG_BYTES = 1 << 20  # a client with more than this unread ...
STALL_S = 1.0  # ... that took none of it for this long is dropped
MAX_CLIENTS = 16
_MAX_QUEUED = 10_000  # frames waiting for the server thread (the oldest go first)
_FLUSH_TIMEOUT_S = 2.0
_POLL_S = 0.05


class IgtlError(SpotnavError):
    """The OpenIGTLink server cannot be set up as asked (a bad name, a port in use)."""


@dataclass(frozen=True)
class _Pose:
    frame: int
    estimate: PoseEstimate
    timestamp_s: float
    mode: str


class PoseServer:
    """An OpenIGTLink server that sends each frame's pose and status (see the module's docstring).

    Parameters
    ----------
    port : int
        TCP port (OpenIGTLink's default is 18944; 0: a free one, see :attr:`port`).
    host : str
        Address to listen on; the loopback interface by default.
    device : str
        The TRANSFORM's device name, ASCII, at most 14 characters (its STRING adds ``Status``).

    Raises
    ------
    IgtlError
        For a bad device name or port, or an address it cannot listen on (naming it).

    Use it as a context manager; leaving it sends what is queued (up to 2 s) and stops the server.
    """

    def __init__(self, port: int = DEFAULT_PORT, *, host: str = DEFAULT_HOST, device: str = DEFAULT_DEVICE) -> None:
        if not 0 <= port < 65536:
            raise IgtlError(f"--igtl port must be in 1..65535, got {port}")
        if not (device.isascii() and device.isprintable() and 0 < len(device + _STATUS_SUFFIX) <= _DEVICE_BYTES):
            limit = _DEVICE_BYTES - len(_STATUS_SUFFIX)
            raise IgtlError(f"--igtl-device must be 1 to {limit} printable ASCII characters, got {device!r}")
        try:
            self._listener = socket.create_server((host, port))
        except OSError as error:
            raise IgtlError(f"OpenIGTLink: cannot listen on {host}:{port}: {error.strerror or error}") from None
        self._listener.setblocking(False)
        self.host, self.port, self.device = host, int(self._listener.getsockname()[1]), device
        self.clients_served = 0
        self.clients_dropped = 0
        self.clients_refused = 0
        self.error = ""  # why the server thread stopped, if it failed
        self._clients: dict[socket.socket, bytearray] = {}
        self._progress: dict[socket.socket, float] = {}  # when each client last took data (or joined)
        self._queue: deque[_Pose] = deque(maxlen=_MAX_QUEUED)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._wake_read, self._wake_write = socket.socketpair()
        self._wake_write.setblocking(False)
        self._last_matrix = np.eye(4)
        self._selector = selectors.DefaultSelector()  # used by the server thread only
        self._selector.register(self._listener, selectors.EVENT_READ)
        self._selector.register(self._wake_read, selectors.EVENT_READ)
        self._thread = threading.Thread(target=self._serve, name="spotnav-igtl", daemon=True)
        self._thread.start()

    @property
    def pending_frames(self) -> int:
        """Frames queued by :meth:`send` that the server thread has not packed for its clients yet."""
        with self._lock:
            return len(self._queue)

    def wait_for_client(self, timeout_s: float, stop: Callable[[], bool] = lambda: False) -> bool:
        """Wait up to ``timeout_s`` for a client, or until ``stop()``; returns whether one is connected."""
        deadline = time.monotonic() + timeout_s
        while not self.connected and time.monotonic() < deadline and not stop():
            time.sleep(0.01)
        return self.connected

    @property
    def connected(self) -> bool:
        """Whether a client is connected."""
        with self._lock:
            return bool(self._clients)

    def send(self, estimate: PoseEstimate, frame: int, timestamp_s: float, mode: str = "") -> None:
        """Queue a frame's pose and status for every client (returns at once; the server thread sends).

        Parameters
        ----------
        estimate : PoseEstimate
        frame : int
            The frame's index.
        timestamp_s : float
            The frame's capture time, Unix seconds.
        mode : str
            The tracker's mode for the frame (``tracked``, ...).

        Raises
        ------
        IgtlError
            If the server thread has stopped on an error.
        """
        if not self._thread.is_alive() and not self._stop.is_set():
            raise IgtlError(f"OpenIGTLink: the server stopped: {self.error or 'unknown error'}")
        with self._lock:
            self._queue.append(_Pose(frame, estimate, timestamp_s, mode))
        self._wake()

    def close(self) -> None:
        """Send what is queued (up to 2 s), then stop the server and close every connection."""
        self._stop.set()
        self._wake()
        self._thread.join(_FLUSH_TIMEOUT_S + 1.0)
        for sock in (self._listener, self._wake_read, self._wake_write):
            sock.close()

    def __enter__(self) -> PoseServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _wake(self) -> None:
        try:
            self._wake_write.send(b"\0")
        except OSError:  # the pipe is full (the server is awake anyway) or closed
            pass

    def _serve(self) -> None:
        """The server thread: accept, discard what clients send, write what waits for them, until closed."""
        selector = self._selector
        deadline = None
        try:
            while True:
                if self._stop.is_set() and deadline is None:
                    deadline = time.monotonic() + _FLUSH_TIMEOUT_S
                self._pack_queued()
                with self._lock:
                    pending = {sock: bool(buffer) for sock, buffer in self._clients.items()}
                if deadline is not None and (not any(pending.values()) or time.monotonic() > deadline):
                    break
                for sock, has_data in pending.items():
                    events = selectors.EVENT_READ | (selectors.EVENT_WRITE if has_data else 0)
                    selector.modify(sock, events)
                for key, events in selector.select(_POLL_S):
                    self._handle(key.fileobj, events)  # type: ignore[arg-type]
                self._drop_stalled()
        except Exception as error:
            self.error = f"{type(error).__name__}: {error}"
        finally:
            with self._lock:
                clients = list(self._clients)
                self._clients.clear()
            for sock in clients:
                selector.unregister(sock)
                sock.close()
            selector.close()

    def _handle(self, sock: socket.socket, events: int) -> None:
        if sock is self._listener:
            self._accept()
        elif sock is self._wake_read:
            try:
                sock.recv(4096)
            except OSError:
                pass
        else:
            try:
                if events & selectors.EVENT_READ and not sock.recv(65536):  # the client closed
                    raise ConnectionResetError
                if events & selectors.EVENT_WRITE:
                    with self._lock:
                        buffer = self._clients[sock]
                        sent = sock.send(buffer)
                        del buffer[:sent]
                        if sent:
                            self._progress[sock] = time.monotonic()
            except BlockingIOError:
                pass
            except OSError:
                self._drop(sock)

    def _accept(self) -> None:
        while True:
            try:
                sock, _ = self._listener.accept()
            except OSError:  # nobody waiting (BlockingIOError) or the client gave up
                return
            with self._lock:
                full = len(self._clients) >= MAX_CLIENTS
            if full:
                self.clients_refused += 1
                sock.close()
                continue
            try:
                sock.setblocking(False)
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            except OSError:  # the client is gone already
                sock.close()
                continue
            with self._lock:
                self._clients[sock] = bytearray()
                self._progress[sock] = time.monotonic()
                self.clients_served += 1
            self._selector.register(sock, selectors.EVENT_READ)

    def _drop(self, sock: socket.socket) -> None:
        with self._lock:
            self._clients.pop(sock, None)
            self._progress.pop(sock, None)
        self._selector.unregister(sock)
        sock.close()

    def _drop_stalled(self) -> None:
        """Drop the clients with over :data:`MAX_BACKLOG_BYTES` waiting that took none of it for :data:`STALL_S`."""
        now = time.monotonic()
        with self._lock:
            stalled = [
                sock
                for sock, buffer in self._clients.items()
                if len(buffer) > MAX_BACKLOG_BYTES and now - self._progress[sock] > STALL_S
            ]
        for sock in stalled:
            self.clients_dropped += 1
            self._drop(sock)

    def _pack_queued(self) -> None:
        with self._lock:
            poses = list(self._queue)
            self._queue.clear()
        if not poses:
            return
        data = b"".join(self._pack(pose) for pose in poses)
        with self._lock:
            for buffer in self._clients.values():
                buffer += data

    def _pack(self, pose: _Pose) -> bytes:
        estimate = pose.estimate
        if estimate.tip_in_eye is not None and estimate.axis is not None and estimate.ok:
            self._last_matrix = instrument_to_eye(estimate.tip_in_eye, estimate.axis, estimate.roll)
        stamp = pose.timestamp_s if np.isfinite(pose.timestamp_s) and pose.timestamp_s >= 0 else time.time()
        transform = pyigtl.TransformMessage(self._last_matrix, timestamp=stamp, device_name=self.device)
        status = {"frame": pose.frame, "status": estimate.status, "mode": pose.mode}
        if np.isfinite(estimate.sigma_mm):
            status["sigma_mm"] = round(float(estimate.sigma_mm), 6)
        if estimate.status == "mismatch":  # what of the setup the frame, or the sequence, contradicts
            status["detail"] = estimate.detail
        text = pyigtl.StringMessage(json.dumps(status), timestamp=stamp, device_name=self.device + _STATUS_SUFFIX)
        transform.header_version = 2
        transform.metadata = {"TransformStatus": "OK" if estimate.ok else "INVALID", "Status": estimate.status}
        packed: bytes = transform.pack() + text.pack()
        return packed
