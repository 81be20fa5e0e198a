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

Both carry the frame's capture time as their timestamp. A pose that stops
updating does not stay valid: when no frame has been sent for ``stale_s``
(0.5 s by default, as SlicerIGT's watchdog), a watchdog on the server's thread
sends the last pose again as ``INVALID`` (metadata ``Status`` = ``stale``) with
a STRING ``{"frame": 12, "status": "stale", "mode": "tracked",
"seconds_since_frame": 0.5, "detail": "no frame for 0.50 s"}`` stamped with
the time it is sent, and again every ``stale_s`` while no frame comes; the
next frame's pose clears it.

The server is spotnav's own loop around pyigtl's message classes, on its own
thread. It acts on nothing clients send: it reads their messages' headers only
to skip their bodies, and drops a client whose bytes are not OpenIGTLink
(reported once, with its address). A client that closes or fails is dropped, a
client that stops reading is dropped once over 1 MiB waits for it and none of
it went out for a second, and at most 16 clients are served at once, so that
no client can stall tracking or starve another. OpenIGTLink has no
authentication: the server listens on the loopback interface unless told
otherwise.
"""

from __future__ import annotations

import json
import selectors
import socket
import struct
import sys
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
    "DEFAULT_STALE_S",
    "MAX_BACKLOG_BYTES",
    "MAX_CLIENTS",
    "SETTLE_S",
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
DEFAULT_STALE_S = 0.5  # no frame for this long: the last pose is sent again as INVALID, stale
SETTLE_S = 0.25  # a client connected this long is one that stays (wait_for_client)
# An OpenIGTLink header: version, type, device name, timestamp, body size, CRC (big-endian, 58 bytes).
_HEADER = struct.Struct(">H12s20sQQQ")
_MAX_BODY_BYTES = 1 << 32  # a header that announces a longer body is not OpenIGTLink
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


def _is_name(field: bytes, required: bool) -> bool:
    """Whether a header's name field is printable ASCII padded with NULs (and not empty, if ``required``)."""
    name = field.rstrip(b"\0")
    return (bool(name) or not required) and all(32 <= byte < 127 for byte in name)


class _Incoming:
    """What one client sends, read only to tell OpenIGTLink from garbage: each header checked, each body skipped."""

    def __init__(self) -> None:
        self._header = bytearray()
        self._skip = 0

    def feed(self, data: bytes) -> bool:
        """Take the next bytes; returns False once they are not OpenIGTLink."""
        view = memoryview(data)
        while view:
            if self._skip:
                taken = min(self._skip, len(view))
                self._skip -= taken
                view = view[taken:]
                continue
            need = _HEADER.size - len(self._header)
            self._header += view[:need]
            view = view[need:]
            if len(self._header) >= 2 and not 1 <= int.from_bytes(self._header[:2]) <= 3:
                return False
            if len(self._header) < _HEADER.size:
                return True
            _, kind, device, _, body, _ = _HEADER.unpack(self._header)
            self._header.clear()
            if not (_is_name(kind, required=True) and _is_name(device, required=False) and body <= _MAX_BODY_BYTES):
                return False
            self._skip = body
        return True


def _to_stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


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
    stale_s : float
        After this long without a frame, s, the last pose is sent again as stale (0: never).
    report : callable, optional
        Takes the warning about a client that sent garbage, once per client, from the server's thread (default:
        stderr).

    Raises
    ------
    IgtlError
        For a bad device name or port, or an address it cannot listen on (naming it).

    Use it as a context manager; leaving it sends what is queued (up to 2 s) and stops the server.
    """

    def __init__(
        self,
        port: int = DEFAULT_PORT,
        *,
        host: str = DEFAULT_HOST,
        device: str = DEFAULT_DEVICE,
        stale_s: float = DEFAULT_STALE_S,
        report: Callable[[str], None] = _to_stderr,
    ) -> None:
        if not (np.isfinite(stale_s) and stale_s >= 0):
            raise IgtlError(f"--igtl-stale must be a finite number of seconds >= 0, got {stale_s}")
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
        self.clients_garbage = 0  # dropped for sending what is not OpenIGTLink
        self.stale_s, self.report = stale_s, report
        self.error = ""  # why the server thread stopped, if it failed
        self._clients: dict[socket.socket, bytearray] = {}
        self._progress: dict[socket.socket, float] = {}  # when each client last took data (or joined)
        self._joined: dict[socket.socket, tuple[float, str]] = {}  # when each client joined, and its address
        self._incoming: dict[socket.socket, _Incoming] = {}  # used by the server thread only
        self._last_sent: tuple[float, _Pose] | None = None  # when send() queued the last frame, and it
        self._stale_at = -np.inf  # when the watchdog last said the pose is stale (server thread only)
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
        """Wait up to ``timeout_s`` for a client that stays, or until ``stop()``; returns whether one came.

        A client that stays is one still connected :data:`SETTLE_S` after it joined: one that connects and
        closes at once (a port scan, a health check) or sends garbage does not count.
        """
        deadline = time.monotonic() + timeout_s
        while not self.settled and time.monotonic() < deadline and not stop():
            time.sleep(0.01)
        return self.settled

    @property
    def settled(self) -> bool:
        """Whether a client has been connected for :data:`SETTLE_S` at least."""
        now = time.monotonic()
        with self._lock:
            return any(now - joined >= SETTLE_S for joined, _ in self._joined.values())

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
        pose = _Pose(frame, estimate, timestamp_s, mode)
        with self._lock:
            self._queue.append(pose)
            self._last_sent = (time.monotonic(), pose)
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
                timeout = self._watch() if deadline is None else _POLL_S
                with self._lock:
                    pending = {sock: bool(buffer) for sock, buffer in self._clients.items()}
                if deadline is not None and (not any(pending.values()) or time.monotonic() > deadline):
                    break
                for sock, has_data in pending.items():
                    events = selectors.EVENT_READ | (selectors.EVENT_WRITE if has_data else 0)
                    selector.modify(sock, events)
                for key, events in selector.select(timeout):
                    self._handle(key.fileobj, events)  # type: ignore[arg-type]
                self._drop_stalled()
        except Exception as error:
            self.error = f"{type(error).__name__}: {error}"
        finally:
            with self._lock:
                clients = list(self._clients)
                self._clients.clear()
                self._joined.clear()
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
                if events & selectors.EVENT_READ and not self._receive(sock):
                    return
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

    def _receive(self, sock: socket.socket) -> bool:
        """Read what ``sock`` sent; drop it (False) if that is garbage.

        Raises
        ------
        OSError
            If the client closed or failed.
        """
        data = sock.recv(65536)
        if not data:  # the client closed
            raise ConnectionResetError
        if self._incoming[sock].feed(data):
            return True
        with self._lock:
            address = self._joined[sock][1]
        self.clients_garbage += 1
        self.report(f"spotnav: warning: OpenIGTLink: {address} sent what is not OpenIGTLink: dropped")
        self._drop(sock)
        return False

    def _accept(self) -> None:
        while True:
            try:
                sock, peer = self._listener.accept()
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
                self._joined[sock] = (time.monotonic(), f"{peer[0]}:{peer[1]}")
                self.clients_served += 1
            self._incoming[sock] = _Incoming()
            self._selector.register(sock, selectors.EVENT_READ)

    def _drop(self, sock: socket.socket) -> None:
        with self._lock:
            self._clients.pop(sock, None)
            self._progress.pop(sock, None)
            self._joined.pop(sock, None)
        self._incoming.pop(sock, None)
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
        self._append(b"".join(self._pack(pose) for pose in poses))

    def _append(self, data: bytes) -> None:
        """Queue ``data`` for every client."""
        with self._lock:
            for buffer in self._clients.values():
                buffer += data

    def _watch(self) -> float:
        """The watchdog: say the pose is stale when it is due; returns how long to wait for the next time, s."""
        with self._lock:
            last = self._last_sent
        if last is None or self.stale_s <= 0:
            return _POLL_S
        sent_s, pose = last
        now = time.monotonic()
        due = sent_s + self.stale_s if self._stale_at < sent_s else self._stale_at + self.stale_s
        if now >= due:
            quiet = now - sent_s
            status = {"frame": pose.frame, "status": "stale", "mode": pose.mode}
            status |= {"seconds_since_frame": round(quiet, 3), "detail": f"no frame for {quiet:.2f} s"}
            self._append(self._messages(time.time(), status, "INVALID"))
            self._stale_at, due = now, now + self.stale_s
        return min(_POLL_S, max(due - now, 0.0))

    def _pack(self, pose: _Pose) -> bytes:
        estimate = pose.estimate
        if estimate.tip_in_eye is not None and estimate.axis is not None and estimate.ok:
            self._last_matrix = instrument_to_eye(estimate.tip_in_eye, estimate.axis, estimate.roll)
        stamp = pose.timestamp_s if np.isfinite(pose.timestamp_s) and pose.timestamp_s >= 0 else time.time()
        status: dict[str, object] = {"frame": pose.frame, "status": estimate.status, "mode": pose.mode}
        if np.isfinite(estimate.sigma_mm):
            status["sigma_mm"] = round(float(estimate.sigma_mm), 6)
        if estimate.status == "mismatch":  # what of the setup the frame, or the sequence, contradicts
            status["detail"] = estimate.detail
        return self._messages(stamp, status, "OK" if estimate.ok else "INVALID")

    def _messages(self, stamp: float, status: dict[str, object], validity: str) -> bytes:
        """The TRANSFORM of the last pose, marked ``validity``, and the STRING of ``status``, packed."""
        transform = pyigtl.TransformMessage(self._last_matrix, timestamp=stamp, device_name=self.device)
        text = pyigtl.StringMessage(json.dumps(status), timestamp=stamp, device_name=self.device + _STATUS_SUFFIX)
        transform.header_version = 2
        transform.metadata = {"TransformStatus": validity, "Status": str(status["status"])}
        packed: bytes = transform.pack() + text.pack()
        return packed
